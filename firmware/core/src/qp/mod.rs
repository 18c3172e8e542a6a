//! Dense box-constrained QP solver, hand-written for the MPC:
//!
//! `min ½ zᵀHz + gᵀz  subject to  lb ≤ z ≤ ub`, `H` symmetric positive definite.
//!
//! - **Fast gradient method** (Nesterov's constant-step scheme for strongly
//!   convex functions) on the Jacobi-preconditioned problem (`z = D z̃`,
//!   `D = diag(H)^{-1/2}`: the box stays a box), warm-started. Each
//!   iteration is one pass over the scaled Hessian's columns (`BoxQp::step`):
//!   gradient, projected step and optimality certificate together.
//! - **Certified accuracy.** Every iterate carries a certificate: an upper
//!   bound on `f(z) − f*` from the prox-gradient inequality with strong
//!   convexity (`f(w) ≥ f(x⁺) + ⟨G, w − y⟩ + ‖G‖²/2L + μ‖w − y‖²/2` for all
//!   `w` in the box, minimised over the box coordinate by coordinate). The
//!   solve stops when the certificate is at most `accuracy`.
//! - **Iteration bounds** (Richter, Jones & Morari, IEEE TAC 2012): after a
//!   first projected-gradient step `x₁`, `f(x_k) − f* ≤ (1 − √(μ/L))^(k−1) ·
//!   2(f(x₁) − f*)`. With `f(x₁) − f*` bounded by the box's diameter this is
//!   the **a-priori bound** `BoxQp::iteration_bound` (independent of the
//!   data: the worst case); with it bounded by `x₁`'s certificate it is the
//!   **solve's own bound**, never larger, which the solve runs in full when the
//!   certificate has not stopped it first. Either way the configured accuracy is
//!   proved, not hoped for; only a cap below the bound (`max_iterations`)
//!   gives up the proof, and the status says so.
//! - **Active-set polish**: the free variables are solved exactly with the
//!   others fixed at their bounds (one LU); the result is kept only if it is
//!   feasible and its certificate is no worse.
//!
//! Every solve returns a point inside the box, with its iteration count,
//! residual, objective and certified gap, even when stopped early. No
//! allocation.

mod exact;
pub use exact::{Blocks, MAX_BLOCK};

use crate::linalg::{lu_solve, symmetric_eigenvalues};
use crate::lit;
use crate::math::{clamp, max as fmax};
use nalgebra::{RealField, SMatrix, SVector};

/// Why a QP could not be set up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum QpError {
    /// H has NaN/∞.
    NonFinite,
    /// H is not positive definite (or the eigenvalue sweep failed).
    NotPositiveDefinite,
}

impl core::fmt::Display for QpError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            QpError::NonFinite => "QP Hessian has NaN/inf",
            QpError::NotPositiveDefinite => "QP Hessian is not positive definite (or its eigenvalue sweep failed)",
        })
    }
}

impl core::error::Error for QpError {}

/// How a solve ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum QpStatus {
    /// The returned point's certificate proves `f(z) − f* ≤ accuracy`.
    Converged,
    /// The active-set polish produced a point whose certificate proves the
    /// accuracy (usually the exact solution).
    Polished,
    /// The solve's iteration bound was run in full: the accuracy holds by the
    /// bound's theorem (in exact arithmetic), while the certificate of the
    /// returned point, computed in the solver's float type, is larger
    /// ([`QpSolution::gap`] says by how much).
    BoundReached,
    /// Stopped by `max_iterations` below the bound: feasible, accuracy
    /// not proved.
    IterationLimit,
    /// Solved by enumerating every active set of the Hessian's independent
    /// blocks ([`Blocks`]): the exact minimiser in exact arithmetic after a
    /// fixed amount of work; [`QpSolution::gap`] certifies the returned
    /// point in the solver's float type.
    Exact,
    /// g, lb or ub had NaN/∞ or lb > ub: the returned point is the projection
    /// of the warm start (or the box centre) and no iteration was made.
    InvalidData,
}

/// A solve's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpSolution<T: RealField + Copy, const N: usize> {
    /// The solution, always inside the box.
    pub z: SVector<T, N>,
    /// FGM iterations taken.
    pub iterations: u32,
    /// The a-priori bound (objective accuracy `QpSettings::accuracy`
    /// guaranteed once reached, whatever the data).
    pub iteration_bound: u32,
    /// This solve's own bound, from its first iterate's certificate (at
    /// most `iteration_bound`): the iterations it would run without an early
    /// stop.
    pub solve_bound: u32,
    /// Certified upper bound on `objective − f*` at `z` (same units as the
    /// objective), computed in the solver's float type.
    pub gap: T,
    /// Optimality measure at `z`: `‖z − Π(z − (Hz + g))‖∞`.
    pub residual: T,
    /// `½ zᵀHz + gᵀz`.
    pub objective: T,
    /// How it ended.
    pub status: QpStatus,
}

/// Solver settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QpSettings<T> {
    /// Stop as soon as the accuracy is proved (by the certificate or by the
    /// solve's own bound). `false`: run `min(max_iterations, a-priori bound)`
    /// iterations whatever happens — a fixed-time solve, and how the worst
    /// case is measured.
    pub early_exit: bool,
    /// Objective accuracy (absolute, the objective's units) to prove.
    pub accuracy: T,
    /// Hard cap on iterations (at least one is always taken). Below the
    /// a-priori bound it can stop a solve before its accuracy is proved
    /// ([`QpStatus::IterationLimit`]).
    pub max_iterations: u32,
    /// Try the active-set polish.
    pub polish: bool,
    /// Solve exactly by enumeration ([`Blocks`]) when the Hessian splits
    /// into independent blocks of at most [`MAX_BLOCK`] variables (`false`:
    /// always the fast gradient method).
    pub enumerate: bool,
}

impl<T: RealField + Copy> Default for QpSettings<T> {
    fn default() -> Self {
        Self {
            early_exit: true,
            accuracy: lit(1e-9),
            max_iterations: 100_000,
            polish: true,
            enumerate: true,
        }
    }
}

/// A QP with a fixed Hessian: everything that depends only on `H` is
/// computed once here.
///
/// ```
/// use fc_core::qp::{BoxQp, QpSettings, QpStatus};
/// use nalgebra::{Matrix2, Vector2};
///
/// // min ½‖z‖² − 2 z₁ + z₂ over the box [0, 1]²: the unconstrained optimum
/// // (2, −1) lies outside; with H = I the answer is its projection, (1, 0).
/// let qp = BoxQp::new(&Matrix2::<f64>::identity())?;
/// let (lb, ub) = (Vector2::new(0.0, 0.0), Vector2::new(1.0, 1.0));
/// let sol = qp.solve(&Vector2::new(-2.0, 1.0), &lb, &ub, &Vector2::zeros(), &QpSettings::default());
/// assert!((sol.z - Vector2::new(1.0, 0.0)).amax() < 1e-9);
/// // H = I is two independent blocks of one variable: solved exactly.
/// assert_eq!(sol.status, QpStatus::Exact);
/// // The fast gradient method instead, within its a-priori bound:
/// let fgm = QpSettings { enumerate: false, ..QpSettings::default() };
/// let sol = qp.solve(&Vector2::new(-2.0, 1.0), &lb, &ub, &Vector2::zeros(), &fgm);
/// assert!((sol.z - Vector2::new(1.0, 0.0)).amax() < 1e-9);
/// assert!(matches!(sol.status, QpStatus::Converged | QpStatus::Polished));
/// assert!(sol.iterations <= sol.iteration_bound); // the a-priori bound holds
/// # Ok::<(), fc_core::qp::QpError>(())
/// ```
#[derive(Debug, Clone)]
// `repr(C)` keeps the scaled Hessian first, so that the iteration's loads
// of it are single instructions with an immediate offset (Thumb-2's VLDR
// reaches 1020 bytes; a 16×16 f32 matrix is 1024).
#[repr(C)]
pub struct BoxQp<T: RealField + Copy, const N: usize> {
    /// Scaled Hessian D H D.
    hs: SMatrix<T, N, N>,
    h: SMatrix<T, N, N>,
    /// Diagonal scaling D.
    d: SVector<T, N>,
    /// Largest / smallest eigenvalue of the scaled Hessian.
    l: T,
    mu: T,
    /// Per variable: the smallest eigenvalue of the scaled Hessian's block
    /// it belongs to (≥ `mu`; `mu` when the Hessian has no small blocks).
    /// The objective is strongly convex with it in each block's own
    /// variables, which tightens the certificate ([`BoxQp::certificate`]).
    mu_var: SVector<T, N>,
    beta: T,
    /// `ln(1 − √(μ/L))`, the bound's rate per iteration (< 0).
    ln_rate: T,
    /// 1 / L, the step size.
    inv_l: T,
    /// The Hessian's independent blocks, when they are small enough to
    /// enumerate.
    blocks: Option<Blocks<N>>,
}

/// One coordinate of a certificate: `min_{w ∈ [lo, hi]} [g(w − y) + μ/2 (w − y)²]`
/// (scaled units), attained at `w − y = clamp(−g/μ, lo − y, hi − y)`.
#[inline(always)]
fn certificate_term<T: RealField + Copy>(g: T, y: T, lo: T, hi: T, inv_mu: T, half_mu: T) -> T {
    let t = clamp(-g * inv_mu, lo - y, hi - y);
    t * (g + half_mu * t)
}

/// How often the early-exit test certifies the iterate (iterations).
const CHECK_EVERY: u32 = 4;

/// The scaled data and iterates of one solve (`z̃ = z / d`).
struct Work<T, const N: usize> {
    gs: [T; N],
    lbs: [T; N],
    ubs: [T; N],
    /// Current iterate and momentum point.
    x: [T; N],
    y: [T; N],
}

impl<T: RealField + Copy, const N: usize> BoxQp<T, N> {
    /// Prepares the solver for Hessian `h` (symmetrised).
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub fn new(h: &SMatrix<T, N, N>) -> Result<Self, QpError> {
        if !h.iter().all(|v| v.is_finite()) {
            return Err(QpError::NonFinite);
        }
        let h = (h + h.transpose()) * lit::<T>(0.5);
        let mut d = SVector::<T, N>::zeros();
        for i in 0..N {
            if h[(i, i)] <= T::zero() {
                return Err(QpError::NotPositiveDefinite);
            }
            d[i] = T::one() / h[(i, i)].sqrt();
        }
        let hs = SMatrix::<T, N, N>::from_fn(|i, j| d[i] * h[(i, j)] * d[j]);
        let eig = symmetric_eigenvalues(&hs).ok_or(QpError::NotPositiveDefinite)?;
        let l = eig.max();
        let mu = eig.min();
        if !(mu > T::zero() && l.is_finite()) {
            return Err(QpError::NotPositiveDefinite);
        }
        let (sl, smu) = (l.sqrt(), mu.sqrt());
        let blocks = Blocks::of(&h);
        let mut mu_var = SVector::<T, N>::repeat(mu);
        for idx in blocks.iter().flat_map(|b| b.each()) {
            // The block alone: its entries of the scaled Hessian, L + 1 on
            // the other diagonal entries (so the least eigenvalue is the block's).
            let mut m = SMatrix::<T, N, N>::identity() * (l + T::one());
            for &i in idx {
                for &j in idx {
                    m[(i as usize, j as usize)] = hs[(i as usize, j as usize)];
                }
            }
            let mu_b = symmetric_eigenvalues(&m).map_or(mu, |e| e.min()).max(mu);
            for &i in idx {
                mu_var[i as usize] = mu_b;
            }
        }
        Ok(Self {
            blocks,
            mu_var,
            h,
            hs,
            d,
            l,
            mu,
            beta: (sl - smu) / (sl + smu),
            ln_rate: Self::ln_rate_of(l, mu),
            inv_l: T::one() / l,
        })
    }

    /// The solver of the identity Hessian (what [`BoxQp::new`] gives for
    /// `I`, without computing it): a placeholder that design overwrites.
    pub fn identity() -> Self {
        let one = SVector::<T, N>::repeat(T::one());
        Self {
            h: SMatrix::identity(),
            hs: SMatrix::identity(),
            d: one,
            l: T::one(),
            mu: T::one(),
            mu_var: one,
            beta: T::zero(),
            ln_rate: Self::ln_rate_of(T::one(), T::one()),
            inv_l: T::one(),
            blocks: Blocks::of(&SMatrix::<T, N, N>::identity()),
        }
    }

    /// The Hessian's independent blocks when every one has at most
    /// [`MAX_BLOCK`] variables (then [`QpSettings::enumerate`] solves exactly).
    pub fn blocks(&self) -> Option<&Blocks<N>> {
        self.blocks.as_ref()
    }

    /// `ln(1 − √(μ/L))`; a very negative number when μ = L (one step solves).
    fn ln_rate_of(l: T, mu: T) -> T {
        let rate = T::one() - (mu / l).sqrt();
        if rate > T::zero() {
            rate.ln()
        } else {
            lit(-1e3)
        }
    }

    /// The Hessian.
    pub fn hessian(&self) -> &SMatrix<T, N, N> {
        &self.h
    }

    /// Condition number of the preconditioned Hessian, L/μ.
    pub fn condition(&self) -> T {
        self.l / self.mu
    }

    /// A-priori iteration bound for objective accuracy `eps` (absolute) over a
    /// box of bounds `lb`, `ub` (Richter, Jones & Morari): independent of `g`
    /// and of the warm start. Saturates at `u32::MAX`.
    pub fn iteration_bound(&self, lb: &SVector<T, N>, ub: &SVector<T, N>, eps: T) -> u32 {
        // Squared diameter of the scaled box (z̃ = z / d).
        let mut d2 = T::zero();
        for i in 0..N {
            let w = (ub[i] - lb[i]) / self.d[i];
            d2 += w * w;
        }
        // f(x₁) − f* + μ/2‖x₁ − x*‖² ≤ (L + μ)/2 · D² after the first step.
        let start = (self.l + self.mu) * lit::<T>(0.5) * d2;
        self.iterations_for(start, eps)
    }

    /// Iterations (the first projected-gradient step included) that prove
    /// accuracy `eps` when `f(x₁) − f* + μ/2‖x₁ − x*‖² ≤ start` after the
    /// first step. Saturates at `u32::MAX`; 1 when `start ≤ eps`.
    fn iterations_for(&self, start: T, eps: T) -> u32 {
        let usable = eps.is_finite() && eps > T::zero() && start.is_finite() && start >= T::zero();
        if !usable {
            return u32::MAX;
        }
        if start <= eps {
            return 1;
        }
        let i = (eps / start).ln() / self.ln_rate;
        let i = libm::ceil(nalgebra::try_convert::<T, f64>(i).unwrap_or(f64::INFINITY));
        // +1 for the first projected-gradient step the bound assumes.
        if i.is_finite() && i < (u32::MAX - 1) as f64 {
            i as u32 + 1
        } else {
            u32::MAX
        }
    }

    /// `½ zᵀHz + gᵀz`.
    pub fn objective(&self, z: &SVector<T, N>, g: &SVector<T, N>) -> T {
        (self.h * z).dot(z) * lit::<T>(0.5) + g.dot(z)
    }

    /// Optimality measure `‖z − Π(z − (Hz + g))‖∞` (0 exactly at the solution).
    pub fn residual(&self, z: &SVector<T, N>, g: &SVector<T, N>, lb: &SVector<T, N>, ub: &SVector<T, N>) -> T {
        Self::residual_at(z, &(self.h * z + g), lb, ub)
    }

    /// [`BoxQp::residual`] with the gradient `Hz + g` at `z` already known.
    fn residual_at(z: &SVector<T, N>, grad: &SVector<T, N>, lb: &SVector<T, N>, ub: &SVector<T, N>) -> T {
        let mut r = T::zero();
        for i in 0..N {
            let p = clamp(z[i] - grad[i], lb[i], ub[i]);
            r = fmax(r, (z[i] - p).abs());
        }
        r
    }

    /// Solves the QP from the warm start `z0` (projected into the box first).
    ///
    /// The loop, in named steps: `start` scales the data, `step` takes a
    /// projected gradient step from the momentum point, certifies its result
    /// and moves to the next momentum point; `finish` unscales, polishes and
    /// certifies the returned point.
    pub fn solve(
        &self,
        g: &SVector<T, N>,
        lb: &SVector<T, N>,
        ub: &SVector<T, N>,
        z0: &SVector<T, N>,
        settings: &QpSettings<T>,
    ) -> QpSolution<T, N> {
        let data_ok =
            g.iter().chain(lb.iter()).chain(ub.iter()).all(|v| v.is_finite()) && (0..N).all(|i| lb[i] <= ub[i]);
        if !data_ok {
            return Self::invalid(lb, ub, z0);
        }
        if let (Some(blocks), true) = (&self.blocks, settings.enumerate) {
            let (z, dual) = blocks.solve(&self.h, g, lb, ub);
            return self.exact(g, lb, ub, z, dual);
        }
        let eps = settings.accuracy;
        let bound = self.iteration_bound(lb, ub, eps);
        let mut w = self.start(g, lb, ub, z0);
        // The first step is a plain projected gradient step (y = x): its
        // certificate bounds everything after it.
        // (β = 0: the fast gradient method starts at x₁ without momentum.)
        let gap1 = self.step::<true>(&mut w, T::zero());
        let solve_bound = self.iterations_for(gap1 + gap1, eps).min(bound);
        let run = if settings.early_exit { solve_bound } else { bound };
        let cap = run.min(settings.max_iterations);
        // The first step is always taken (also with `max_iterations` 0).
        let mut iterations = 1u32;
        let mut gap = gap1;
        while iterations < cap && !(settings.early_exit && gap <= eps) {
            // The certificate costs a fifth of an iteration: computed every
            // CHECK_EVERY iterations, in a fixed-time solve too, so that the
            // fixed-time solve is the worst case in instructions as well.
            gap = if iterations.is_multiple_of(CHECK_EVERY) {
                self.step::<true>(&mut w, self.beta)
            } else {
                self.step::<false>(&mut w, self.beta)
            };
            iterations += 1;
        }
        let proved_by_bound = iterations >= solve_bound;
        self.finish(g, lb, ub, &w, settings, iterations, bound, solve_bound, proved_by_bound)
    }

    /// The answer to invalid data: the warm start clamped into whatever box is sane.
    fn invalid(lb: &SVector<T, N>, ub: &SVector<T, N>, z0: &SVector<T, N>) -> QpSolution<T, N> {
        let mut z = SVector::<T, N>::zeros();
        for i in 0..N {
            let (lo, hi) = (lb[i], ub[i]);
            let v = if z0[i].is_finite() { z0[i] } else { T::zero() };
            z[i] = if lo.is_finite() && hi.is_finite() && lo <= hi {
                v.max(lo).min(hi)
            } else {
                T::zero()
            };
        }
        let big = T::max_value().unwrap_or(T::one());
        QpSolution {
            z,
            iterations: 0,
            iteration_bound: 0,
            solve_bound: 0,
            gap: big,
            residual: big,
            objective: big,
            status: QpStatus::InvalidData,
        }
    }

    /// Scales the data (`g̃ = D g`, box / D) and projects the warm start.
    fn start(&self, g: &SVector<T, N>, lb: &SVector<T, N>, ub: &SVector<T, N>, z0: &SVector<T, N>) -> Work<T, N> {
        let zero = [T::zero(); N];
        let mut w = Work {
            gs: zero,
            lbs: zero,
            ubs: zero,
            x: zero,
            y: zero,
        };
        for i in 0..N {
            let d = self.d[i];
            w.gs[i] = g[i] * d;
            w.lbs[i] = lb[i] / d;
            w.ubs[i] = ub[i] / d;
            let v = if z0[i].is_finite() { z0[i] / d } else { T::zero() };
            w.x[i] = clamp(v, w.lbs[i], w.ubs[i]);
        }
        w.y = w.x;
        w
    }

    /// One iteration from the momentum point `y`: gradient `∇ = H̃y + g̃`
    /// (column by column, the sums held in registers), projected step
    /// `x⁺ᵢ = Π(yᵢ − ∇ᵢ/L)`, the next momentum point `y ← x⁺ + β(x⁺ − x)`
    /// (`beta` 0 restarts the momentum), and when `CERTIFY` the certificate
    /// of `x⁺` from the gradient mapping `Gᵢ = L(yᵢ − x⁺ᵢ)`:
    /// `f(x⁺) − f* ≤ −Σᵢ min_{wᵢ ∈ box} [Gᵢ(wᵢ − yᵢ) + μ/2 (wᵢ − yᵢ)²] − ‖G‖²/2L`.
    /// Returns the certificate (≥ 0; `T::max_value()` when not `CERTIFY`).
    // Out of line: inlined into a caller whose `self` is a field far into
    // a larger struct, every load of H̃ would need its address computed.
    #[inline(never)]
    #[allow(clippy::needless_range_loop)] // five arrays indexed alike
    fn step<const CERTIFY: bool>(&self, w: &mut Work<T, N>, beta: T) -> T {
        let mut grad = w.gs;
        for (col, &yj) in self.hs.as_slice().chunks_exact(N).zip(w.y.iter()) {
            for (gi, &h) in grad.iter_mut().zip(col.iter()) {
                *gi += h * yj;
            }
        }
        let (l, inv_l) = (self.l, self.inv_l);
        let inv_mu = T::one() / self.mu;
        let half_mu = self.mu * lit::<T>(0.5);
        let mut low = T::zero();
        let mut g2 = T::zero();
        for i in 0..N {
            let yi = w.y[i];
            let xi = clamp(yi - grad[i] * inv_l, w.lbs[i], w.ubs[i]);
            if CERTIFY {
                let gi = (yi - xi) * l;
                low += certificate_term(gi, yi, w.lbs[i], w.ubs[i], inv_mu, half_mu);
                g2 += gi * gi;
            }
            w.y[i] = xi + (xi - w.x[i]) * beta;
            w.x[i] = xi;
        }
        if !CERTIFY {
            return T::max_value().unwrap_or(T::one());
        }
        let gap = -low - g2 * inv_l * lit::<T>(0.5);
        if gap > T::zero() {
            gap
        } else {
            T::zero()
        }
    }

    /// Certificate of a feasible point `z` from its gradient `grad = Hz + g`
    /// (original units): `f(z) − f* ≤ −Σᵢ min_{w̃ᵢ ∈ box} [∇̃ᵢ(w̃ᵢ − z̃ᵢ) + μ/2 (w̃ᵢ − z̃ᵢ)²]`
    /// in the scaled coordinates, with each variable's μ that of its
    /// independent block (`mu_var`: the objective is the sum of the blocks'
    /// objectives, each strongly convex with its own μ in its own variables).
    /// Rounding in the gradient enters as `δ²/(2μ)`, so the block's μ, not
    /// the least over all blocks, keeps the certificate near the true gap.
    fn certificate(&self, z: &SVector<T, N>, grad: &SVector<T, N>, lb: &SVector<T, N>, ub: &SVector<T, N>) -> T {
        let mut low = T::zero();
        for i in 0..N {
            let (d, mu) = (self.d[i], self.mu_var[i]);
            let (inv_mu, half_mu) = (T::one() / mu, mu * lit::<T>(0.5));
            low += certificate_term(grad[i] * d, z[i] / d, lb[i] / d, ub[i] / d, inv_mu, half_mu);
        }
        if low < T::zero() {
            -low
        } else {
            T::zero()
        }
    }

    /// The answer of the enumeration, with its certificate: one pass, no
    /// iterations to bound. The certificate is the lesser of the
    /// strong-convexity bound ([`BoxQp::certificate`]) and the blocks'
    /// duality gap `dual` (both bound the same gap).
    fn exact(
        &self,
        g: &SVector<T, N>,
        lb: &SVector<T, N>,
        ub: &SVector<T, N>,
        z: SVector<T, N>,
        dual: Option<T>,
    ) -> QpSolution<T, N> {
        let grad = self.h * z + g;
        let strong = self.certificate(&z, &grad, lb, ub);
        QpSolution {
            objective: z.dot(&(grad + g)) * lit::<T>(0.5),
            gap: dual.map_or(strong, |d| d.min(strong)),
            residual: Self::residual_at(&z, &grad, lb, ub),
            z,
            iterations: 1,
            iteration_bound: 1,
            solve_bound: 1,
            status: QpStatus::Exact,
        }
    }

    /// Unscales the last iterate, tries the polish, and certifies what is returned.
    #[allow(clippy::too_many_arguments)]
    fn finish(
        &self,
        g: &SVector<T, N>,
        lb: &SVector<T, N>,
        ub: &SVector<T, N>,
        w: &Work<T, N>,
        settings: &QpSettings<T>,
        iterations: u32,
        bound: u32,
        solve_bound: u32,
        proved_by_bound: bool,
    ) -> QpSolution<T, N> {
        // Unscaling can round a bound-active value one ulp outside: clamp.
        let mut z = SVector::<T, N>::zeros();
        for i in 0..N {
            z[i] = clamp(w.x[i] * self.d[i], lb[i], ub[i]);
        }
        let mut grad = self.h * z + g;
        let mut gap = self.certificate(&z, &grad, lb, ub);
        let mut polished = false;
        if settings.polish && gap > T::zero() {
            if let Some(zp) = self.polish(&z, g, lb, ub) {
                let gp = self.h * zp + g;
                let cp = self.certificate(&zp, &gp, lb, ub);
                if cp <= gap {
                    z = zp;
                    grad = gp;
                    gap = cp;
                    polished = true;
                }
            }
        }
        let residual = Self::residual_at(&z, &grad, lb, ub);
        let status = match (gap <= settings.accuracy, polished) {
            (true, true) => QpStatus::Polished,
            (true, false) => QpStatus::Converged,
            (false, _) if proved_by_bound => QpStatus::BoundReached,
            (false, _) => QpStatus::IterationLimit,
        };
        QpSolution {
            // ½zᵀHz + gᵀz = ½zᵀ(∇ + g).
            objective: z.dot(&(grad + g)) * lit::<T>(0.5),
            z,
            iterations,
            iteration_bound: bound,
            solve_bound,
            gap,
            residual,
            status,
        }
    }

    /// Exact solve on the active set guessed from `z`: variables at a bound
    /// whose gradient pushes outward stay fixed; the rest solve H_FF z_F =
    /// −(g_F + H_FA z_A). `None` if the result leaves the box or is singular.
    fn polish(
        &self,
        z: &SVector<T, N>,
        g: &SVector<T, N>,
        lb: &SVector<T, N>,
        ub: &SVector<T, N>,
    ) -> Option<SVector<T, N>> {
        let grad = self.h * z + g;
        let mut fixed = [false; N];
        for i in 0..N {
            let span = (ub[i] - lb[i]).abs().max(T::one());
            let near = lit::<T>(1e-9) * span;
            fixed[i] = (z[i] - lb[i] <= near && grad[i] >= T::zero()) || (ub[i] - z[i] <= near && grad[i] <= T::zero());
        }
        let mut m = SMatrix::<T, N, N>::zeros();
        let mut rhs = SVector::<T, N>::zeros();
        for i in 0..N {
            if fixed[i] {
                m[(i, i)] = T::one();
                rhs[i] = z[i];
            } else {
                rhs[i] = -g[i];
                for j in 0..N {
                    if fixed[j] {
                        rhs[i] -= self.h[(i, j)] * z[j];
                    } else {
                        m[(i, j)] = self.h[(i, j)];
                    }
                }
            }
        }
        let zp = lu_solve(&m, &rhs)?;
        let slack = lit::<T>(1e-12);
        for i in 0..N {
            let span = (ub[i] - lb[i]).abs().max(T::one()) * slack;
            if zp[i] < lb[i] - span || zp[i] > ub[i] + span {
                return None;
            }
        }
        let mut out = zp;
        for i in 0..N {
            out[i] = zp[i].max(lb[i]).min(ub[i]);
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests;
