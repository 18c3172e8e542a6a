//! Dense box-constrained QP solver, hand-written for the MPC:
//!
//! `min ½ zᵀHz + gᵀz  subject to  lb ≤ z ≤ ub`, `H` symmetric positive definite.
//!
//! - **Fast gradient method** (Nesterov's constant-step scheme for strongly
//!   convex functions) on the Jacobi-preconditioned problem (`z = D z̃`,
//!   `D = diag(H)^{-1/2}`: the box stays a box), warm-started.
//! - **Stopping rule** on a real optimality measure: the gradient mapping
//!   `‖L(y − Π(y − ∇f(y)/L))‖∞` in the original variables, below a tolerance.
//! - **A-priori iteration bound** (Richter, Jones & Morari, IEEE TAC 2012):
//!   after a first projected-gradient step from any point of the box,
//!   `f(z_i) − f* ≤ (1 − √(μ/L))^i · (L + μ)/2 · D²` with `D` the (scaled) box
//!   diameter, so `i_max = ⌈ln(ε/((L+μ)D²/2)) / ln(1 − √(μ/L))⌉` iterations
//!   reach objective accuracy `ε` whatever the data. Computed once from `H`
//!   (its exact eigenvalues) and the box size.
//! - **Active-set polish**: once the iterate has settled, the free variables
//!   are solved exactly with the others fixed at their bounds (one LU); the
//!   result is kept only if it is feasible and satisfies the KKT signs, which
//!   closes the gap the bound leaves in practice.
//!
//! Every solve returns a point inside the box, with its iteration count,
//! residual and objective, even when stopped early. No allocation.

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
    /// The optimality measure fell below the tolerance.
    Converged,
    /// The active-set polish produced the exact solution.
    Polished,
    /// The iteration limit was reached; the point is feasible, not optimal.
    IterationLimit,
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
    /// The a-priori bound this solve was capped at (objective accuracy
    /// `QpSettings::accuracy` guaranteed once reached).
    pub iteration_bound: u32,
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
    /// Stop early when the optimality measure is at most this (floored at the
    /// float type's rounding of the gradient). Zero or less: never stop early,
    /// run `min(max_iterations, bound)` iterations — a fixed-time solve, and
    /// how the worst case is measured.
    pub tolerance: T,
    /// Objective accuracy (absolute) the a-priori bound guarantees; the
    /// iterations are capped at that bound.
    pub accuracy: T,
    /// Hard cap on iterations, below the bound when real-time demands it.
    pub max_iterations: u32,
    /// Try the active-set polish.
    pub polish: bool,
}

impl<T: RealField + Copy> Default for QpSettings<T> {
    fn default() -> Self {
        Self {
            tolerance: lit(1e-6),
            accuracy: lit(1e-9),
            max_iterations: 100_000,
            polish: true,
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
/// assert!(matches!(sol.status, QpStatus::Converged | QpStatus::Polished));
/// assert!(sol.iterations <= sol.iteration_bound); // the a-priori bound holds
/// # Ok::<(), fc_core::qp::QpError>(())
/// ```
#[derive(Debug, Clone)]
pub struct BoxQp<T: RealField + Copy, const N: usize> {
    h: SMatrix<T, N, N>,
    /// Scaled Hessian D H D.
    hs: SMatrix<T, N, N>,
    /// Diagonal scaling D.
    d: SVector<T, N>,
    /// Largest / smallest eigenvalue of the scaled Hessian.
    l: T,
    mu: T,
    beta: T,
    /// `L / dᵢ`: turns a scaled step into the gradient mapping in original units.
    l_over_d: SVector<T, N>,
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
        Ok(Self {
            h,
            hs,
            d,
            l,
            mu,
            beta: (sl - smu) / (sl + smu),
            l_over_d: d.map(|di| l / di),
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
            beta: T::zero(),
            l_over_d: one,
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
        let start = (self.l + self.mu) * lit::<T>(0.5) * d2;
        if !eps.is_finite() || eps <= T::zero() || start <= eps {
            return 1;
        }
        let rate = T::one() - (self.mu / self.l).sqrt();
        if rate <= T::zero() {
            return 1;
        }
        let i = (eps / start).ln() / rate.ln();
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
        let grad = self.h * z + g;
        let mut r = T::zero();
        for i in 0..N {
            let p = clamp(z[i] - grad[i], lb[i], ub[i]);
            r = fmax(r, (z[i] - p).abs());
        }
        r
    }

    /// Solves the QP from the warm start `z0` (projected into the box first).
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
            // Best effort inside whatever box is sane: clamp the warm start.
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
            return QpSolution {
                z,
                iterations: 0,
                iteration_bound: 0,
                residual: T::max_value().unwrap_or(T::one()),
                objective: T::max_value().unwrap_or(T::one()),
                status: QpStatus::InvalidData,
            };
        }
        // Scaled problem: z = D z̃, g̃ = D g, box / D.
        let gs = g.component_mul(&self.d);
        let lbs = lb.component_div(&self.d);
        let ubs = ub.component_div(&self.d);
        let proj = |v: &SVector<T, N>| {
            let mut o = *v;
            for i in 0..N {
                o[i] = clamp(v[i], lbs[i], ubs[i]);
            }
            o
        };
        let inv_l = T::one() / self.l;
        // The optimality measure cannot go below the rounding of the gradient
        // Hz + g in this float type: floor the tolerance there (f32 and a
        // Hessian of 1e4 put it near 1e-3; f64 near 1e-12).
        let mut width = T::zero();
        for i in 0..N {
            width = width.max(ub[i].abs().max(lb[i].abs()));
        }
        let floor = lit::<T>(4.0 * N as f64) * T::default_epsilon() * (self.h.amax() * width + g.amax());
        let tol = if settings.tolerance > T::zero() {
            settings.tolerance.max(floor)
        } else {
            -T::one()
        };
        let mut x = proj(&z0.component_div(&self.d));
        let mut x_prev = x;
        let mut iterations = 0u32;
        let mut status = QpStatus::IterationLimit;
        let bound = self.iteration_bound(lb, ub, settings.accuracy);
        for it in 0..settings.max_iterations.min(bound) {
            // Momentum point, gradient there, projected step.
            let y = if it == 0 { x } else { x + (x - x_prev) * self.beta };
            let grad = self.hs * y + gs;
            let x_new = proj(&(y - grad * inv_l));
            iterations = it + 1;
            // Gradient mapping back in original units (interior: exactly ‖∇f‖).
            let mut gm = T::zero();
            for i in 0..N {
                gm = fmax(gm, ((y[i] - x_new[i]) * self.l_over_d[i]).abs());
            }
            x_prev = x;
            x = x_new;
            if gm <= tol {
                status = QpStatus::Converged;
                break;
            }
        }
        // Unscaling can round a bound-active value one ulp outside: clamp.
        let mut z = x.component_mul(&self.d);
        for i in 0..N {
            z[i] = z[i].max(lb[i]).min(ub[i]);
        }
        let mut residual = self.residual(&z, g, lb, ub);
        if settings.polish && residual > T::zero() {
            if let Some(zp) = self.polish(&z, g, lb, ub) {
                let rp = self.residual(&zp, g, lb, ub);
                if rp <= residual {
                    z = zp;
                    residual = rp;
                    if rp <= tol {
                        status = QpStatus::Polished;
                    }
                }
            }
        }
        if status == QpStatus::IterationLimit && residual <= tol {
            status = QpStatus::Converged;
        }
        QpSolution {
            objective: self.objective(&z, g),
            z,
            iterations,
            iteration_bound: bound,
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
