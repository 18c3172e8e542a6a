//! Heading scheduling for the hover LQRs: gains designed at `H` headings
//! evenly spread over a turn and interpolated linearly between them.

use super::ControlError;
use crate::linalg::{solve_care, solve_dare, RiccatiSolution};
use crate::lit;
use crate::model::{zoh_into, LinearModel, VehicleParams};
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

/// The thesis' input weights `r` (made for the OS4) for the vehicle `p`:
/// each scaled by `(range on the OS4 / range on p)²`, the input ranges
/// being the input box's upper limits, so that every input costs the same
/// fraction of its range as on the OS4 (Bryson's rule, `R ∝ 1/u_max²`).
/// On a 30 g vehicle whose thrust is 1/22 of the OS4's, the thesis' own
/// weights would make the inputs ≈ 500× cheaper and the gains saturate
/// them. The factors are exactly 1 on the OS4.
pub fn inputs_weighted_for<T: RealField + Copy>(r: &SMatrix<f64, 4, 4>, p: &VehicleParams<T>) -> SMatrix<f64, 4, 4> {
    // Both ranges in `p`'s float type: on the OS4 the ratio is exactly 1.
    let os4 = VehicleParams::<f64>::OS4.cast::<T>().input_box().hi;
    let this = p.input_box().hi;
    let mut out = *r;
    for i in 0..4 {
        let k = nalgebra::try_convert::<T, f64>(os4[i] / this[i]).unwrap_or(f64::NAN);
        if k.is_finite() && k > 0.0 {
            for j in 0..4 {
                out[(i, j)] *= k;
                out[(j, i)] *= k;
            }
        }
    }
    out
}

#[cfg(test)]
mod input_weight_tests {
    use super::*;

    #[test]
    fn input_weights_follow_the_vehicles_input_ranges() {
        let r = SMatrix::<f64, 4, 4>::from_diagonal(&nalgebra::Vector4::new(1.0, 2.0, 3.0, 4.0));
        // The OS4 itself, in either float type: the thesis' weights unchanged.
        assert_eq!(inputs_weighted_for(&r, &VehicleParams::<f64>::OS4), r);
        assert_eq!(inputs_weighted_for(&r, &VehicleParams::<f32>::os4()), r);
        // Half the thrust coefficient halves the force ranges (×4 on their
        // weights); half the moment coefficient the yaw range.
        let p = VehicleParams {
            kf_ns2: VehicleParams::<f64>::OS4.kf_ns2 / 2.0,
            km_nms2: VehicleParams::<f64>::OS4.km_nms2 / 2.0,
            ..VehicleParams::OS4
        };
        let w = inputs_weighted_for(&r, &p);
        for (i, want) in [4.0, 8.0, 12.0, 16.0].iter().enumerate() {
            assert!((w[(i, i)] - want).abs() < 1e-9, "{w}");
        }
    }
}
