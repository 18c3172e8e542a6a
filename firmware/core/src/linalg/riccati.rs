//! Algebraic Riccati equations by the structure-preserving doubling
//! algorithm (SDA), fixed size, no allocation, bounded iterations.
//!
//! - Discrete (DARE): `X = AᵀXA − AᵀXB(R + BᵀXB)⁻¹BᵀXA + Q`, SDA from
//!   `A₀ = A, G₀ = BR⁻¹Bᵀ, H₀ = Q`.
//! - Continuous (CARE): `AᵀX + XA − XBR⁻¹BᵀX + Q = 0`, mapped to the same
//!   doubling by the Cayley transform with shift γ (Chu, Fan & Lin, 2005):
//!   `Aγ = A − γI`, `Wγ = Aγᵀ + Q Aγ⁻¹ G`, `Vγ = Aγ + G Aγ⁻ᵀ Q`,
//!   `A₀ = I + 2γ Vγ⁻¹`, `G₀ = 2γ Aγ⁻¹ G Wγ⁻¹`, `H₀ = 2γ Wγ⁻¹ Q Aγ⁻¹`.
//!
//! Each doubling step is `W = I + GH`, `A ← A W⁻¹ A`, `G ← G + A W⁻¹ G Aᵀ`,
//! `H ← H + Aᵀ H W⁻¹ A`; `H` converges quadratically to the stabilising `X`.

use super::lu::{inverse, lu_solve};
use crate::lit;
use nalgebra::{RealField, SMatrix};

/// Most doubling steps taken (each squares the contraction factor).
pub const MAX_DOUBLINGS: u32 = 64;

/// Why a Riccati solve failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RiccatiError {
    /// An input contained NaN/∞.
    NonFinite,
    /// A matrix that must be inverted was singular (R, I + GH, the shifted A, …).
    Singular,
    /// No convergence within [`MAX_DOUBLINGS`] steps (no stabilising solution).
    NotConverged,
}

impl core::fmt::Display for RiccatiError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            RiccatiError::NonFinite => "Riccati input has NaN/inf",
            RiccatiError::Singular => "a matrix the Riccati solver must invert is singular (R, I + GH, shifted A)",
            RiccatiError::NotConverged => "the Riccati doubling did not converge (no stabilising solution)",
        })
    }
}

impl core::error::Error for RiccatiError {}

/// A Riccati solution with its state-feedback gain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RiccatiSolution<T: RealField + Copy, const N: usize, const M: usize> {
    /// The stabilising solution X (symmetric, positive semi-definite).
    pub x: SMatrix<T, N, N>,
    /// Gain K of the control law `u = −K x`.
    pub k: SMatrix<T, M, N>,
    /// Doubling steps taken.
    pub iterations: u32,
}

fn finite<T: RealField + Copy, const R: usize, const C: usize>(m: &SMatrix<T, R, C>) -> bool {
    m.iter().all(|v| v.is_finite())
}

fn inv<T: RealField + Copy, const N: usize>(m: &SMatrix<T, N, N>) -> Result<SMatrix<T, N, N>, RiccatiError> {
    inverse(m).ok_or(RiccatiError::Singular)
}

fn symmetrise<T: RealField + Copy, const N: usize>(m: &SMatrix<T, N, N>) -> SMatrix<T, N, N> {
    (m + m.transpose()) * lit::<T>(0.5)
}

/// Relative convergence tolerance on ‖ΔH‖/‖H‖ for this float type.
fn tolerance<T: RealField + Copy>() -> T {
    T::default_epsilon() * lit::<T>(64.0)
}

/// Accepts a solution whose Riccati residual is small against the size of the
/// equation's terms (√ε relative: f64 ≈ 1.5e-8, f32 ≈ 3.5e-4).
fn check_residual<T: RealField + Copy, const N: usize>(res: &SMatrix<T, N, N>, size: T) -> Result<(), RiccatiError> {
    let r = res.amax();
    if r.is_finite() && size.is_finite() && r <= T::default_epsilon().sqrt() * size.max(T::one()) {
        Ok(())
    } else {
        Err(RiccatiError::NotConverged)
    }
}

/// The SDA doubling loop from `(A₀, G₀, H₀)`; returns `H∞` and the steps taken.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
fn doubling<T: RealField + Copy, const N: usize>(
    mut a: SMatrix<T, N, N>,
    mut g: SMatrix<T, N, N>,
    mut h: SMatrix<T, N, N>,
) -> Result<(SMatrix<T, N, N>, u32), RiccatiError> {
    let id = SMatrix::<T, N, N>::identity();
    let tol = tolerance::<T>();
    for it in 1..=MAX_DOUBLINGS {
        let w = id + g * h;
        let wa = lu_solve(&w, &a).ok_or(RiccatiError::Singular)?; // W⁻¹A
        let wg = lu_solve(&w, &g).ok_or(RiccatiError::Singular)?; // W⁻¹G
        let h_next = symmetrise(&(h + a.transpose() * h * wa));
        let g_next = symmetrise(&(g + a * wg * a.transpose()));
        let a_next = a * wa;
        if !(finite(&h_next) && finite(&g_next) && finite(&a_next)) {
            return Err(RiccatiError::NotConverged);
        }
        // Max-norms: no squaring, so no overflow before the finiteness check.
        let change = (h_next - h).amax();
        let scale = h_next.amax();
        h = h_next;
        g = g_next;
        a = a_next;
        if scale.is_finite() && (change <= tol * scale || a.amax() <= tol) {
            return Ok((h, it));
        }
    }
    Err(RiccatiError::NotConverged)
}

/// Checks the data and forms `R⁻¹` and `G = BR⁻¹Bᵀ`, shared by both equations.
#[allow(clippy::type_complexity)]
fn prepare<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    q: &SMatrix<T, N, N>,
    r: &SMatrix<T, M, M>,
) -> Result<(SMatrix<T, M, M>, SMatrix<T, N, N>), RiccatiError> {
    if !(finite(a) && finite(b) && finite(q) && finite(r)) {
        return Err(RiccatiError::NonFinite);
    }
    let rinv = inv(r)?;
    let g = symmetrise(&(b * rinv * b.transpose()));
    Ok((rinv, g))
}

/// Solves the discrete ARE for `x⁺ = A x + B u` with stage cost `xᵀQx + uᵀRu`;
/// the gain is `K = (R + BᵀXB)⁻¹BᵀXA`.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn solve_dare<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    q: &SMatrix<T, N, N>,
    r: &SMatrix<T, M, M>,
) -> Result<RiccatiSolution<T, N, M>, RiccatiError> {
    let (_, g) = prepare(a, b, q, r)?;
    let (x, iterations) = doubling(*a, g, symmetrise(q))?;
    let s = r + b.transpose() * x * b;
    let k = lu_solve(&s, &(b.transpose() * x * a)).ok_or(RiccatiError::Singular)?;
    // Independent acceptance test: the DARE residual, relative to its terms.
    let ax = a.transpose() * x * a;
    let res = ax - a.transpose() * x * b * k + q - x;
    check_residual(&res, ax.amax() + q.amax() + x.amax())?;
    Ok(RiccatiSolution { x, k, iterations })
}

/// Solves the continuous ARE for `ẋ = A x + B u` with cost `∫ xᵀQx + uᵀRu dt`;
/// the gain is `K = R⁻¹BᵀX`.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn solve_care<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    q: &SMatrix<T, N, N>,
    r: &SMatrix<T, M, M>,
) -> Result<RiccatiSolution<T, N, M>, RiccatiError> {
    let (rinv, g) = prepare(a, b, q, r)?;
    let q = symmetrise(q);
    // Shift: of the order of A's and the coupling's size, so that Aγ and Wγ are
    // well conditioned; any γ > 0 that is not an eigenvalue of A is valid.
    let gamma = (a.norm() + (g.norm() * q.norm()).sqrt()).max(T::one());
    let two_g = lit::<T>(2.0) * gamma;
    let id = SMatrix::<T, N, N>::identity();
    let ag = a - id * gamma;
    let ag_inv = inv(&ag)?;
    let w = ag.transpose() + q * ag_inv * g;
    let v = ag + g * ag_inv.transpose() * q;
    let w_inv = inv(&w)?;
    let v_inv = inv(&v)?;
    let a0 = id + v_inv * two_g;
    let g0 = symmetrise(&(ag_inv * g * w_inv * two_g));
    let h0 = symmetrise(&(w_inv * q * ag_inv * two_g));
    let (x, iterations) = doubling(a0, g0, h0)?;
    let k = rinv * b.transpose() * x;
    // Independent acceptance test: the CARE residual, relative to its terms.
    let xa = x * a;
    let xgx = x * g * x;
    let res = xa.transpose() + xa - xgx + q;
    check_residual(&res, xa.amax() + xgx.amax() + q.amax())?;
    Ok(RiccatiSolution { x, k, iterations })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Matrix2, SMatrix, Vector2};

    #[test]
    fn scalar_care_matches_closed_form() {
        // ẋ = a x + b u: X = (a + sqrt(a² + b²q/r)) r / b².
        for &(a, b, q, r) in &[(1.0f64, 1.0, 1.0, 1.0), (-2.0, 0.5, 3.0, 0.1), (0.0, 2.0, 5.0, 2.0)] {
            let s = solve_care(&Matrix1::new(a), &Matrix1::new(b), &Matrix1::new(q), &Matrix1::new(r)).unwrap();
            let want = (a + (a * a + b * b * q / r).sqrt()) * r / (b * b);
            assert!(
                (s.x[0] - want).abs() < 1e-12 * want.abs().max(1.0),
                "{} vs {want}",
                s.x[0]
            );
            assert!((s.k[0] - b * want / r).abs() < 1e-12 * want.abs().max(1.0));
        }
    }

    #[test]
    fn double_integrator_care_matches_closed_form() {
        // ẍ = u, Q = I, R = 1: X = [[√3, 1], [1, √3]], K = [1, √3].
        let a = Matrix2::new(0.0, 1.0, 0.0, 0.0);
        let b = Vector2::new(0.0, 1.0);
        let s = solve_care(&a, &b, &Matrix2::identity(), &Matrix1::new(1.0)).unwrap();
        let r3 = 3f64.sqrt();
        assert!((s.x - Matrix2::new(r3, 1.0, 1.0, r3)).amax() < 1e-12, "{}", s.x);
        assert!((s.k - SMatrix::<f64, 1, 2>::new(1.0, r3)).amax() < 1e-12);
    }

    #[test]
    fn scalar_dare_matches_closed_form() {
        // x⁺ = a x + b u: b²X² + (r(1 − a²) − b²q) X − q r = 0.
        let (a, b, q, r) = (1.2f64, 0.7, 2.0, 0.5);
        let s = solve_dare(&Matrix1::new(a), &Matrix1::new(b), &Matrix1::new(q), &Matrix1::new(r)).unwrap();
        let (qa, qb, qc) = (b * b, r * (1.0 - a * a) - b * b * q, -q * r);
        let want = (-qb + (qb * qb - 4.0 * qa * qc).sqrt()) / (2.0 * qa);
        assert!((s.x[0] - want).abs() < 1e-12 * want, "{} vs {want}", s.x[0]);
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let a = Matrix2::new(0.0, 1.0, 0.0, 0.0);
        let b = Vector2::new(0.0, 1.0);
        let q = Matrix2::identity();
        assert_eq!(
            solve_care(&a, &b, &q, &Matrix1::new(0.0)).unwrap_err(),
            RiccatiError::Singular
        );
        assert_eq!(
            solve_care(&a, &b, &q, &Matrix1::new(f64::NAN)).unwrap_err(),
            RiccatiError::NonFinite
        );
        // Unstabilisable: an unstable mode that B cannot reach.
        let a2 = Matrix2::new(1.0, 0.0, 0.0, -1.0);
        let b2 = Vector2::new(0.0, 1.0);
        assert!(solve_dare(&(a2 * 2.0), &b2, &q, &Matrix1::new(1.0)).is_err());
    }
}
