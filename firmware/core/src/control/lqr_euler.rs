//! LQR about hover, Euler form (thesis 3.91–3.100; weights Table 4.5),
//! `U = Uss − K(ψ) δX`, scheduled on the current heading ψ.

use super::lqr_table::{design_discrete, inputs_weighted_for, GainTable};
use super::{
    observer::AccelObserver, validate, wrap_pi, AttitudeRef, ControlError, ControlOutput, Controller, ReferenceMode,
    Setpoint, StateEstimate,
};
use crate::model::{euler_hover_model, InputBox, Vehicle, VehicleParams};
use nalgebra::{RealField, SMatrix, SVector, Vector4};

/// Thesis Table 4.5: `Q = diag(10 20 90 5 5 15 10 20 35 85 5 1)`, `R = diag(1 .1 .1 .1)`.
pub fn euler_weights() -> (SMatrix<f64, 12, 12>, SMatrix<f64, 4, 4>) {
    let q = SVector::<f64, 12>::from([10.0, 20.0, 90.0, 5.0, 5.0, 15.0, 10.0, 20.0, 35.0, 85.0, 5.0, 1.0]);
    let r = Vector4::new(1.0, 0.1, 0.1, 0.1);
    (SMatrix::from_diagonal(&q), SMatrix::from_diagonal(&r))
}

/// The project's weights: Table 4.5's with the pitch rate weighted 40
/// instead of 5. Table 4.5's light pitch-rate weight leaves a pitch loop that
/// slow rotors (0.2 s) with half the rotational drag turn unstable: the
/// robustness sweep's worst corner diverged (docs/book/src/model.md §8.6). 85, the
/// roll rate's weight, holds the corner too but slows the pitch loop enough
/// that a 5 s circle's x RMSE grows past 0.2 m; 20 and 40 hold both.
pub fn tuned_weights() -> (SMatrix<f64, 12, 12>, SMatrix<f64, 4, 4>) {
    let (mut q, r) = euler_weights();
    q[(10, 10)] = 40.0;
    (q, r)
}

/// The Euler LQR with `H` scheduled headings (default 36, every 10°).
#[derive(Debug, Clone)]
pub struct LqrEuler<T: RealField + Copy, const H: usize = 36> {
    vehicle: Vehicle<T>,
    table: GainTable<T, H>,
    mode: ReferenceMode,
    bx: InputBox<T>,
    obs: AccelObserver<T>,
}

impl<T: RealField + Copy, const H: usize> LqrEuler<T, H> {
    /// Designs the discrete gains at sample time `ts` (s) for the model
    /// `params` with weights `q`, `r` (continuous-time, per second).
    pub fn new(
        params: VehicleParams<T>,
        q: &SMatrix<f64, 12, 12>,
        r: &SMatrix<f64, 4, 4>,
        ts: f64,
        mode: ReferenceMode,
    ) -> Result<Self, ControlError> {
        let mut me = Self::blank(params, mode);
        me.redesign(params, q, r, ts, mode)?;
        Ok(me)
    }

    /// A controller with an all-zero gain table: the storage that
    /// [`LqrEuler::redesign`] fills in place. Not a controller until then.
    pub fn blank(params: VehicleParams<T>, mode: ReferenceMode) -> Self {
        Self {
            bx: params.input_box(),
            vehicle: Vehicle::new(&params),
            table: GainTable::zeros(),
            mode,
            obs: AccelObserver::off(),
        }
    }

    /// Gives this controller integral action: the disturbance observer
    /// `obs` ([`AccelObserver`]) whose estimate the attitude and thrust
    /// targets cancel (in place: see [`LqrEuler::redesign`]).
    pub fn set_observer(&mut self, obs: AccelObserver<T>) {
        self.obs = obs;
    }

    /// The disturbance observer (off for the thesis weights).
    pub fn observer(&self) -> &AccelObserver<T> {
        &self.obs
    }

    /// Designs this controller in place, as [`LqrEuler::new`] would (the
    /// table is large: designing in place keeps a second copy off the
    /// stack). On error the table is incomplete: design it again.
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub fn redesign(
        &mut self,
        params: VehicleParams<T>,
        q: &SMatrix<f64, 12, 12>,
        r: &SMatrix<f64, 4, 4>,
        ts: f64,
        mode: ReferenceMode,
    ) -> Result<(), ControlError> {
        let p64: VehicleParams<f64> = params.cast();
        if !p64.is_valid() {
            return Err(ControlError::InvalidParameter);
        }
        self.bx = params.input_box();
        self.vehicle = Vehicle::new(&params);
        self.mode = mode;
        self.table
            .redesign(|yaw| Ok(design_discrete(&euler_hover_model(&p64, yaw), q, r, ts)?.k))
    }

    /// The thesis weights (Table 4.5), the input weights kept relative to
    /// this vehicle's input ranges ([`inputs_weighted_for`]; the thesis'
    /// own on the OS4).
    pub fn thesis(params: VehicleParams<T>, ts: f64, mode: ReferenceMode) -> Result<Self, ControlError> {
        let (q, r) = euler_weights();
        let r = inputs_weighted_for(&r, &params);
        Self::new(params, &q, &r, ts, mode)
    }

    /// [`LqrEuler::redesign`] with the thesis weights (Table 4.5).
    pub fn redesign_thesis(
        &mut self,
        params: VehicleParams<T>,
        ts: f64,
        mode: ReferenceMode,
    ) -> Result<(), ControlError> {
        let (q, r) = euler_weights();
        let r = inputs_weighted_for(&r, &params);
        self.redesign(params, &q, &r, ts, mode)
    }

    /// The scheduled gain at heading `yaw` (rad).
    pub fn gain(&self, yaw: T) -> SMatrix<T, 4, 12> {
        self.table.at(yaw)
    }
}

impl<T: RealField + Copy, const H: usize> Controller<T> for LqrEuler<T, H> {
    fn update(&mut self, est: &StateEstimate<T>, sp: &Setpoint<T>) -> Result<ControlOutput<T>, ControlError> {
        validate(est, sp)?;
        let e = est.euler();
        self.obs.observe(est);
        let ar = AttitudeRef::with_disturbance(&self.vehicle.params, sp, self.mode, &self.obs.estimate());
        let mut dx = SVector::<T, 12>::zeros();
        dx.fixed_rows_mut::<3>(0).copy_from(&(est.pos_ned_m - sp.pos_ned_m));
        dx.fixed_rows_mut::<3>(3).copy_from(&(est.vel_ned_mps - sp.vel_ned_mps));
        dx[6] = e[0] - ar.roll_rad;
        dx[7] = e[1] - ar.pitch_rad;
        dx[8] = wrap_pi(e[2] - ar.yaw_rad);
        dx.fixed_rows_mut::<3>(9)
            .copy_from(&(est.rates_frd_radps - ar.rates_frd_radps));
        let tff = self.obs.torque_feedforward(&self.vehicle);
        let u_ref = Vector4::new(ar.thrust_n, tff[0], tff[1], tff[2]);
        let raw = u_ref - self.table.at(e[2]) * dx;
        Ok(self.obs.finish(&self.bx, &self.vehicle, est, &raw))
    }

    fn reset(&mut self) {
        self.obs.reset();
    }

    fn elapsed(&mut self, dt_s: T) {
        self.obs.elapsed(dt_s);
    }

    fn resume(&mut self) {
        self.obs.resume();
    }
}
