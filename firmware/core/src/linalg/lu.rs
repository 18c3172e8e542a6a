//! Dense LU with partial pivoting for fixed-size systems, generic over const
//! sizes (nalgebra's own LU needs typenum bounds that const generics lack).

use nalgebra::{RealField, SMatrix};

/// Row exchanges of an LU factorisation: at elimination step `k` row `k`
/// was swapped with row `pivots[k]` (≥ k).
pub type Pivots<const N: usize> = [usize; N];

/// Factors `A` (N×N) in place by Gaussian elimination with partial
/// pivoting: afterwards the upper triangle holds U and the part below the
/// diagonal the multipliers of each step where that step computed them (not
/// permuted by later exchanges, unlike LAPACK's `getrf`), and `pivots` the row exchanges. `false` if
/// `A` is singular to working precision or not finite (then `A` is garbage).
/// O(N³), no allocation, no copy of `A`: the design code factors its
/// scratch matrices where they lie.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn lu_factor_in_place<T: RealField + Copy, const N: usize>(
    m: &mut SMatrix<T, N, N>,
    pivots: &mut Pivots<N>,
) -> bool {
    let scale = m.amax();
    if !(scale.is_finite() && scale > T::zero()) {
        return false;
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
            return false;
        }
        pivots[k] = piv;
        if piv != k {
            // Only the active columns: the multipliers left of k stay in the
            // rows they were computed for, so that `lu_apply_in_place` replays
            // the elimination exactly.
            for j in k..N {
                m.swap((piv, j), (k, j));
            }
        }
        let d = T::one() / m[(k, k)];
        for i in (k + 1)..N {
            let f = m[(i, k)] * d;
            if f != T::zero() {
                for j in (k + 1)..N {
                    let v = m[(k, j)];
                    m[(i, j)] -= f * v;
                }
            }
            m[(i, k)] = f;
        }
    }
    true
}

/// Solves `A X = B` in place (`x` holds B on entry, X on return) from the
/// factors of [`lu_factor_in_place`]: the same row operations, in the same
/// order, as eliminating `[A | B]` at once. `false` if X is not finite.
// Design-time code: see `lu_factor_in_place`.
#[inline(never)]
pub fn lu_apply_in_place<T: RealField + Copy, const N: usize, const C: usize>(
    lu: &SMatrix<T, N, N>,
    pivots: &Pivots<N>,
    x: &mut SMatrix<T, N, C>,
) -> bool {
    for k in 0..N {
        if pivots[k] != k {
            x.swap_rows(pivots[k], k);
        }
        for i in (k + 1)..N {
            let f = lu[(i, k)];
            if f != T::zero() {
                for j in 0..C {
                    let v = x[(k, j)];
                    x[(i, j)] -= f * v;
                }
            }
        }
    }
    // Back substitution.
    for k in (0..N).rev() {
        let d = T::one() / lu[(k, k)];
        for j in 0..C {
            let mut s = x[(k, j)];
            for i in (k + 1)..N {
                s -= lu[(k, i)] * x[(i, j)];
            }
            x[(k, j)] = s * d;
        }
    }
    x.iter().all(|v| v.is_finite())
}

/// Solves `A X = B` for square `A` (N×N) and `B` (N×C) by Gaussian
/// elimination with partial pivoting. `None` if `A` is singular to working
/// precision or the result is not finite. O(N³ + N²C), no allocation.
pub fn lu_solve<T: RealField + Copy, const N: usize, const C: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, C>,
) -> Option<SMatrix<T, N, C>> {
    let mut m = *a;
    let mut x = *b;
    let mut pivots = [0; N];
    (lu_factor_in_place(&mut m, &mut pivots) && lu_apply_in_place(&m, &pivots, &mut x)).then_some(x)
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
