//! Dense LU with partial pivoting for fixed-size systems, generic over const
//! sizes (nalgebra's own LU needs typenum bounds that const generics lack).

use nalgebra::{RealField, SMatrix};

/// Solves `A X = B` for square `A` (N×N) and `B` (N×C) by Gaussian
/// elimination with partial pivoting. `None` if `A` is singular to working
/// precision or the result is not finite. O(N³ + N²C), no allocation.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn lu_solve<T: RealField + Copy, const N: usize, const C: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, C>,
) -> Option<SMatrix<T, N, C>> {
    let mut m = *a;
    let mut x = *b;
    let scale = m.amax();
    if !(scale.is_finite() && scale > T::zero()) {
        return None;
    }
    let tiny = scale * T::default_epsilon() * nalgebra::convert::<f64, T>(N as f64);
    for k in 0..N {
        // Pivot: largest magnitude in column k at or below the diagonal.
        let mut piv = k;
        let mut best = m[(k, k)].abs();
        for i in (k + 1)..N {
            let v = m[(i, k)].abs();
            if v > best {
                best = v;
                piv = i;
            }
        }
        if best <= tiny || !best.is_finite() {
            return None;
        }
        if piv != k {
            m.swap_rows(piv, k);
            x.swap_rows(piv, k);
        }
        let d = T::one() / m[(k, k)];
        for i in (k + 1)..N {
            let f = m[(i, k)] * d;
            if f != T::zero() {
                for j in (k + 1)..N {
                    let v = m[(k, j)];
                    m[(i, j)] -= f * v;
                }
                for j in 0..C {
                    let v = x[(k, j)];
                    x[(i, j)] -= f * v;
                }
            }
            m[(i, k)] = T::zero();
        }
    }
    // Back substitution.
    for k in (0..N).rev() {
        let d = T::one() / m[(k, k)];
        for j in 0..C {
            let mut s = x[(k, j)];
            for i in (k + 1)..N {
                s -= m[(k, i)] * x[(i, j)];
            }
            x[(k, j)] = s * d;
        }
    }
    if x.iter().all(|v| v.is_finite()) {
        Some(x)
    } else {
        None
    }
}

/// Inverse of a square matrix via [`lu_solve`]; `None` when singular.
pub fn inverse<T: RealField + Copy, const N: usize>(a: &SMatrix<T, N, N>) -> Option<SMatrix<T, N, N>> {
    lu_solve(a, &SMatrix::<T, N, N>::identity())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, SMatrix, Vector3};

    #[test]
    fn solves_and_inverts() {
        let a = Matrix3::new(0.0, 2.0, 1.0, 1.0, 1.0, 0.0, 3.0, 0.0, 1.0); // needs pivoting
        let x = Vector3::new(1.0, -2.0, 0.5);
        let b = a * x;
        assert!((lu_solve(&a, &b).unwrap() - x).amax() < 1e-14);
        let ai = inverse(&a).unwrap();
        assert!((ai * a - Matrix3::identity()).amax() < 1e-14);
        // Against nalgebra's inverse on a random 12×12.
        let mut s = 7u64;
        let m = SMatrix::<f64, 12, 12>::from_fn(|_, _| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        });
        let mine = inverse(&m).unwrap();
        let theirs = m.try_inverse().unwrap();
        assert!((mine - theirs).amax() < 1e-9 * theirs.amax());
    }

    #[test]
    fn singular_is_none() {
        let a = Matrix3::new(1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.0, 1.0, 1.0);
        assert!(inverse(&a).is_none());
        assert!(inverse(&Matrix3::<f64>::zeros()).is_none());
        assert!(inverse(&(Matrix3::<f64>::identity() * f64::NAN)).is_none());
    }
}
