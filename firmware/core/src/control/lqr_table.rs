//! Heading scheduling for the hover LQRs: gains designed at `H` headings
//! evenly spread over a turn and interpolated linearly between them.

use super::ControlError;
use crate::linalg::{solve_care, solve_dare, RiccatiSolution};
use crate::lit;
use crate::model::{zoh_into, LinearModel};
use nalgebra::{RealField, SMatrix};

/// LQR gain `K` (4 inputs × 12 states).
pub type Gain<T> = SMatrix<T, 4, 12>;

/// Gains at headings `ψ_i = −π + 2π·i/H`, `i = 0..H`.
#[derive(Debug, Clone)]
pub struct GainTable<T: RealField + Copy, const H: usize> {
    gains: [Gain<T>; H],
}

impl<T: RealField + Copy, const H: usize> GainTable<T, H> {
    /// Heading of table entry `i`, rad.
    pub fn heading(i: usize) -> f64 {
        -core::f64::consts::PI + core::f64::consts::TAU * i as f64 / H as f64
    }

    /// Number of headings in the table.
    pub const LEN: usize = H;

    /// A table of zero gains (storage for [`GainTable::redesign`]).
    pub fn zeros() -> Self {
        Self {
            gains: [Gain::<T>::zeros(); H],
        }
    }

    /// Designs every entry with `design(heading_rad)`; fails on the first error.
    pub fn build(design: impl FnMut(f64) -> Result<Gain<f64>, ControlError>) -> Result<Self, ControlError> {
        let mut me = Self::zeros();
        me.redesign(design)?;
        Ok(me)
    }

    /// Designs every entry in place with `design(heading_rad)`; fails on the
    /// first error (then the table is incomplete: design it again).
    pub fn redesign(
        &mut self,
        mut design: impl FnMut(f64) -> Result<Gain<f64>, ControlError>,
    ) -> Result<(), ControlError> {
        // A table without entries is a type that cannot exist (compile error).
        const { assert!(H > 0, "a gain table needs at least one heading") };
        for (i, g) in self.gains.iter_mut().enumerate() {
            *g = design(Self::heading(i))?.map(|v| lit::<T>(v));
        }
        Ok(())
    }

    /// The gain at heading `yaw` (rad, any value), interpolated between the
    /// two nearest table entries.
    pub fn at(&self, yaw: T) -> Gain<T> {
        let y = nalgebra::try_convert::<T, f64>(yaw).unwrap_or(0.0);
        let y = if y.is_finite() { y } else { 0.0 };
        let mut turn = (y + core::f64::consts::PI) % core::f64::consts::TAU;
        if turn < 0.0 {
            turn += core::f64::consts::TAU;
        }
        let pos = turn / core::f64::consts::TAU * H as f64;
        let i0 = (pos as usize).min(H - 1);
        let i1 = (i0 + 1) % H;
        let f = lit::<T>(pos - i0 as f64);
        self.gains[i0] * (T::one() - f) + self.gains[i1] * f
    }
}

/// Continuous-time LQR of a hover model (CARE): `U = Uss − K δX`.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn design_continuous(
    lm: &LinearModel<f64>,
    q: &SMatrix<f64, 12, 12>,
    r: &SMatrix<f64, 4, 4>,
) -> Result<RiccatiSolution<f64, 12, 4>, ControlError> {
    Ok(solve_care(&lm.a, &lm.b, q, r)?)
}

/// Discrete-time LQR of the same model under zero-order hold at `ts` (s),
/// with the continuous weights scaled by `ts` (the sampled cost), from the
/// same Riccati code (DARE).
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn design_discrete(
    lm: &LinearModel<f64>,
    q: &SMatrix<f64, 12, 12>,
    r: &SMatrix<f64, 4, 4>,
    ts: f64,
) -> Result<RiccatiSolution<f64, 12, 4>, ControlError> {
    if !(ts.is_finite() && ts > 0.0) {
        return Err(ControlError::InvalidParameter);
    }
    let mut ad = SMatrix::<f64, 12, 12>::zeros();
    let mut bd = SMatrix::<f64, 12, 4>::zeros();
    zoh_into(&lm.a, &lm.b, ts, &mut ad, &mut bd)?;
    let mut qs = *q;
    qs.scale_mut(ts);
    let mut rs = *r;
    rs.scale_mut(ts);
    Ok(solve_dare(&ad, &bd, &qs, &rs)?)
}
