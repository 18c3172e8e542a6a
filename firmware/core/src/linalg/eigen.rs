//! Eigenvalues of a symmetric matrix by cyclic Jacobi rotations (fixed size,
//! bounded sweeps). Used offline to get the QP's Lipschitz and strong
//! convexity constants exactly.

use crate::lit;
use nalgebra::{RealField, SMatrix, SVector};

/// Most Jacobi sweeps (each sweep visits every off-diagonal pair once).
pub const MAX_SWEEPS: u32 = 60;

/// Eigenvalues of the symmetric part of `a`, unsorted. `None` if `a` is not
/// finite or the off-diagonal mass does not vanish within [`MAX_SWEEPS`].
pub fn symmetric_eigenvalues<T: RealField + Copy, const N: usize>(a: &SMatrix<T, N, N>) -> Option<SVector<T, N>> {
    if !a.iter().all(|v| v.is_finite()) {
        return None;
    }
    let mut m = (a + a.transpose()) * lit::<T>(0.5);
    let total = m.norm_squared();
    let tol = T::default_epsilon() * T::default_epsilon() * total.max(T::min_value().unwrap_or(T::zero()));
    for _ in 0..MAX_SWEEPS {
        let mut off = T::zero();
        for p in 0..N {
            for q in (p + 1)..N {
                off += m[(p, q)] * m[(p, q)];
            }
        }
        if off <= tol {
            return Some(m.diagonal());
        }
        for p in 0..N {
            for q in (p + 1)..N {
                let apq = m[(p, q)];
                if apq == T::zero() {
                    continue;
                }
                // Rotation that zeroes m[p][q] (Golub & Van Loan, Alg. 8.4.1).
                let tau = (m[(q, q)] - m[(p, p)]) / (lit::<T>(2.0) * apq);
                let t = tau.signum() / (tau.abs() + (T::one() + tau * tau).sqrt());
                let t = if tau == T::zero() { T::one() } else { t };
                let c = T::one() / (T::one() + t * t).sqrt();
                let s = t * c;
                for k in 0..N {
                    let mkp = m[(k, p)];
                    let mkq = m[(k, q)];
                    m[(k, p)] = c * mkp - s * mkq;
                    m[(k, q)] = s * mkp + c * mkq;
                }
                for k in 0..N {
                    let mpk = m[(p, k)];
                    let mqk = m[(q, k)];
                    m[(p, k)] = c * mpk - s * mqk;
                    m[(q, k)] = s * mpk + c * mqk;
                }
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, SMatrix};

    #[test]
    fn matches_known_and_nalgebra_eigenvalues() {
        let a = Matrix3::new(2.0, -1.0, 0.0, -1.0, 2.0, -1.0, 0.0, -1.0, 2.0);
        let mut e: Vec<f64> = symmetric_eigenvalues(&a).unwrap().iter().copied().collect();
        e.sort_by(|x, y| x.partial_cmp(y).unwrap());
        let r2 = 2f64.sqrt();
        for (got, want) in e.iter().zip([2.0 - r2, 2.0, 2.0 + r2]) {
            assert!((got - want).abs() < 1e-13);
        }
        let mut s = 3u64;
        let r = SMatrix::<f64, 16, 16>::from_fn(|_, _| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        });
        let sym = r * r.transpose();
        let mut mine: Vec<f64> = symmetric_eigenvalues(&sym).unwrap().iter().copied().collect();
        let mut theirs: Vec<f64> = sym.symmetric_eigenvalues().iter().copied().collect();
        mine.sort_by(|x, y| x.partial_cmp(y).unwrap());
        theirs.sort_by(|x, y| x.partial_cmp(y).unwrap());
        for (a, b) in mine.iter().zip(&theirs) {
            assert!((a - b).abs() < 1e-12 * theirs[15]);
        }
    }
}
