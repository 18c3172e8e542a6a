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

use super::lu::{inverse, lu_apply_in_place, lu_factor_in_place, lu_solve};
use super::mul_into;
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

/// Symmetrises `m` in place: `(M + Mᵀ)/2`, entry by entry as the
/// expression would compute it (so the diagonal is `(m + m)/2`, too).
#[inline(never)]
fn symmetrise_in_place<T: RealField + Copy, const N: usize>(m: &mut SMatrix<T, N, N>) {
    let half = lit::<T>(0.5);
    for i in 0..N {
        for j in i..N {
            let v = (m[(i, j)] + m[(j, i)]) * half;
            m[(i, j)] = v;
            m[(j, i)] = v;
        }
    }
}

/// The doubling's workspace: the iterates and the products of one step,
/// every one a named N×N buffer written in place, no temporaries (with
/// N = 12 in f64, ≈ 8 KiB: the largest frame of a design).
struct Sda<T: RealField + Copy, const N: usize> {
    /// `Aₖ`.
    a: SMatrix<T, N, N>,
    /// `Gₖ`.
    g: SMatrix<T, N, N>,
    /// `Hₖ` (→ X).
    h: SMatrix<T, N, N>,
    /// `W = I + GH`, then its LU factors; then `A·W⁻¹G`, `AᵀH`; then `Aₖ₊₁`.
    w: SMatrix<T, N, N>,
    /// `W⁻¹A`.
    wa: SMatrix<T, N, N>,
    /// `W⁻¹G`, then `Gₖ₊₁`.
    wg: SMatrix<T, N, N>,
    /// `Aᵀ`, then `Hₖ₊₁`.
    at: SMatrix<T, N, N>,
    /// Row exchanges of W's factors.
    pivots: super::lu::Pivots<N>,
}

impl<T: RealField + Copy, const N: usize> Sda<T, N> {
    /// One doubling step `(A, G, H) → (A W⁻¹A, G + A W⁻¹G Aᵀ, H + AᵀH W⁻¹A)`,
    /// both sums symmetrised; returns `(‖Hₖ₊₁ − Hₖ‖max, ‖Hₖ₊₁‖max)`.
    fn step(&mut self) -> Result<(T, T), RiccatiError> {
        let one = T::one();
        mul_into(&self.g, &self.h, &mut self.w);
        for i in 0..N {
            self.w[(i, i)] += one;
        }
        if !lu_factor_in_place(&mut self.w, &mut self.pivots) {
            return Err(RiccatiError::Singular);
        }
        self.wa.copy_from(&self.a);
        self.wg.copy_from(&self.g);
        if !(lu_apply_in_place(&self.w, &self.pivots, &mut self.wa)
            && lu_apply_in_place(&self.w, &self.pivots, &mut self.wg))
        {
            return Err(RiccatiError::Singular);
        }
        self.a.transpose_to(&mut self.at);
        // Gₖ₊₁ = sym(G + (A W⁻¹G) Aᵀ), into wg.
        mul_into(&self.a, &self.wg, &mut self.w);
        mul_into(&self.w, &self.at, &mut self.wg);
        self.wg += &self.g;
        symmetrise_in_place(&mut self.wg);
        // Hₖ₊₁ = sym(H + (AᵀH)(W⁻¹A)), into at.
        mul_into(&self.at, &self.h, &mut self.w);
        mul_into(&self.w, &self.wa, &mut self.at);
        self.at += &self.h;
        symmetrise_in_place(&mut self.at);
        // Aₖ₊₁ = A W⁻¹A, into w.
        mul_into(&self.a, &self.wa, &mut self.w);
        if !(finite(&self.at) && finite(&self.wg) && finite(&self.w)) {
            return Err(RiccatiError::NotConverged);
        }
        // Max-norms: no squaring, so no overflow before the finiteness check.
        let mut change = T::zero();
        for (n, o) in self.at.iter().zip(self.h.iter()) {
            change = change.max((*n - *o).abs());
        }
        let scale = self.at.amax();
        core::mem::swap(&mut self.h, &mut self.at);
        core::mem::swap(&mut self.g, &mut self.wg);
        core::mem::swap(&mut self.a, &mut self.w);
        Ok((change, scale))
    }
}

impl<T: RealField + Copy, const N: usize> Sda<T, N> {
    /// A workspace starting from `(A₀, G₀, H₀)`.
    fn new(a: &SMatrix<T, N, N>, g: &SMatrix<T, N, N>, h: &SMatrix<T, N, N>) -> Self {
        let z = SMatrix::<T, N, N>::zeros();
        Self {
            a: *a,
            g: *g,
            h: *h,
            w: z,
            wa: z,
            wg: z,
            at: z,
            pivots: [0; N],
        }
    }

    /// The doubling loop; on success `self.h` is `H∞` and the steps taken
    /// are returned.
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    fn run(&mut self) -> Result<u32, RiccatiError> {
        let tol = tolerance::<T>();
        for it in 1..=MAX_DOUBLINGS {
            let (change, scale) = self.step()?;
            if scale.is_finite() && (change <= tol * scale || self.a.amax() <= tol) {
                return Ok(it);
            }
        }
        Err(RiccatiError::NotConverged)
    }
}

/// Checks the data and forms `G = BR⁻¹Bᵀ` (symmetrised) into `g`, shared by
/// both equations; returns `R⁻¹`.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
fn prepare<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    q: &SMatrix<T, N, N>,
    r: &SMatrix<T, M, M>,
    g: &mut SMatrix<T, N, N>,
) -> Result<SMatrix<T, M, M>, RiccatiError> {
    if !(finite(a) && finite(b) && finite(q) && finite(r)) {
        return Err(RiccatiError::NonFinite);
    }
    let rinv = inv(r)?;
    let br = b * rinv;
    mul_into(&br, &b.transpose(), g);
    symmetrise_in_place(g);
    Ok(rinv)
}

/// Solves the discrete ARE for `x⁺ = A x + B u` with stage cost `xᵀQx + uᵀRu`;
/// the gain is `K = (R + BᵀXB)⁻¹BᵀXA`.
///
/// ```
/// use fc_core::linalg::solve_dare;
/// use nalgebra::Matrix1;
///
/// // Scalar, unstable (a = 1.2): X solves b²X² + (r(1 − a²) − b²q)X − qr = 0.
/// let (a, b, q, r) = (1.2, 0.7, 2.0, 0.5);
/// let s = solve_dare(&Matrix1::new(a), &Matrix1::new(b), &Matrix1::new(q), &Matrix1::new(r))?;
/// let (qa, qb, qc): (f64, f64, f64) = (b * b, r * (1.0 - a * a) - b * b * q, -q * r);
/// let x = (-qb + (qb * qb - 4.0 * qa * qc).sqrt()) / (2.0 * qa);
/// assert!((s.x[0] - x).abs() < 1e-12 * x);
/// assert!((a - b * s.k[0]).abs() < 1.0); // the closed loop is stable
/// # Ok::<(), fc_core::linalg::RiccatiError>(())
/// ```
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn solve_dare<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    q: &SMatrix<T, N, N>,
    r: &SMatrix<T, M, M>,
) -> Result<RiccatiSolution<T, N, M>, RiccatiError> {
    let mut sda = Sda::new(a, q, q);
    prepare(a, b, q, r, &mut sda.g)?;
    symmetrise_in_place(&mut sda.h);
    let iterations = sda.run()?;
    let k = dare_gain(a, b, r, &sda.h)?;
    sda.check_dare_residual(a, b, q, &k)?;
    Ok(RiccatiSolution {
        x: sda.h,
        k,
        iterations,
    })
}

/// The DARE's gain `K = (R + BᵀXB)⁻¹BᵀXA`.
// Design-time code: see `solve_dare`.
#[inline(never)]
fn dare_gain<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    r: &SMatrix<T, M, M>,
    x: &SMatrix<T, N, N>,
) -> Result<SMatrix<T, M, N>, RiccatiError> {
    let s = r + b.transpose() * x * b;
    lu_solve(&s, &(b.transpose() * x * a)).ok_or(RiccatiError::Singular)
}

impl<T: RealField + Copy, const N: usize> Sda<T, N> {
    /// Independent acceptance test of the solution `X = self.h`: the DARE
    /// residual `AᵀXA − AᵀXB·K + Q − X`, relative to its terms, formed in the
    /// workspace's free buffers.
    // Design-time code: see `solve_dare`.
    #[inline(never)]
    fn check_dare_residual<const M: usize>(
        &mut self,
        a: &SMatrix<T, N, N>,
        b: &SMatrix<T, N, M>,
        q: &SMatrix<T, N, N>,
        k: &SMatrix<T, M, N>,
    ) -> Result<(), RiccatiError> {
        a.transpose_to(&mut self.at);
        mul_into(&self.at, &self.h, &mut self.w); // AᵀX
        mul_into(&self.w, a, &mut self.wa); // AᵀXA
        let mut xb = SMatrix::<T, N, M>::zeros();
        mul_into(&self.w, b, &mut xb); // AᵀXB
        mul_into(&xb, k, &mut self.wg); // AᵀXB·K
        for i in 0..N {
            for j in 0..N {
                self.g[(i, j)] = self.wa[(i, j)] - self.wg[(i, j)] + q[(i, j)] - self.h[(i, j)];
            }
        }
        check_residual(&self.g, self.wa.amax() + q.amax() + self.h.amax())
    }
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
    let mut g = SMatrix::<T, N, N>::zeros();
    let rinv = prepare(a, b, q, r, &mut g)?;
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
    let mut sda = Sda::new(&a0, &g0, &h0);
    let iterations = sda.run()?;
    let x = sda.h;
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
