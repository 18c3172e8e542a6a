//! LQR about hover, reduced quaternion form `[x y z ẋ ẏ ż q1 q2 q3 p q r]`
//! (q0 eliminated through the unit norm with q0 > 0; thesis 3.95–3.100,
//! weights Table 4.7: Q = I12, R = I4), scheduled on the current heading ψ.
//!
//! The reduced coordinates about `(cos ψT/2, 0, 0, sin ψT/2)` are singular at
//! ψT = ±180° (q0 = 0: roll rate no longer moves q1). This controller
//! therefore works in the frame of the current heading: position and velocity
//! errors rotated by −ψ, attitude as `q_h⁻¹ ⊗ q` with `q_h` the heading
//! quaternion. In that frame the model is the reduced model at ψT = 0 for
//! every heading, exactly (the dynamics are symmetric in yaw and Q weights x
//! and y equally), so one gain serves all headings with no singularity.

use super::lqr_table::{design_discrete, inputs_weighted_for, Gain};
use super::{
    observer::AccelObserver, validate, AttitudeRef, ControlError, ControlOutput, Controller, HeadingFrame,
    ReferenceMode, Setpoint, StateEstimate,
};
use crate::lit;
use crate::model::{euler_to_quat, quat_hover_model, quat_to_euler, InputBox, Vehicle, VehicleParams};
use nalgebra::{RealField, SMatrix, SVector, Vector4};

/// Thesis Table 4.7: `Q = I12`, `R = I4`.
pub fn quat_weights() -> (SMatrix<f64, 12, 12>, SMatrix<f64, 4, 4>) {
    (SMatrix::identity(), SMatrix::identity())
}

/// The project's weights: the Euler LQR's ([`super::lqr_euler::tuned_weights`])
/// in this form's coordinates. Attitude weights ×4 because `q1, q2, q3 ≈
/// φ/2, θ/2, ψ/2`; x and y share Table 4.5's mean (15), as the heading
/// symmetry needs equal weights. Table 4.7's `Q = I` weights a metre of error
/// like a rad/s of rate: the vehicle sags ≈ 2 m under a 15 % heavier load and
/// leaves the 1 m tube on half of the sweep's vehicles; these fly it like the
/// Euler LQR.
pub fn tuned_weights() -> (SMatrix<f64, 12, 12>, SMatrix<f64, 4, 4>) {
    let (qe, r) = super::lqr_euler::tuned_weights();
    let mut q = qe;
    let xy = 0.5 * (qe[(0, 0)] + qe[(1, 1)]);
    q[(0, 0)] = xy;
    q[(1, 1)] = xy;
    for i in 6..9 {
        q[(i, i)] *= 4.0;
    }
    (q, r)
}

/// The quaternion LQR.
#[derive(Debug, Clone)]
pub struct LqrQuat<T: RealField + Copy> {
    vehicle: Vehicle<T>,
    gain: Gain<T>,
    mode: ReferenceMode,
    bx: InputBox<T>,
    obs: AccelObserver<T>,
}

impl<T: RealField + Copy> LqrQuat<T> {
    /// Designs the discrete gain at sample time `ts` (s) for the model
    /// `params` with weights `q`, `r` (continuous-time, per second). The x and
    /// y weights (and those of ẋ, ẏ) must be equal for the heading symmetry.
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub fn new(
        params: VehicleParams<T>,
        q: &SMatrix<f64, 12, 12>,
        r: &SMatrix<f64, 4, 4>,
        ts: f64,
        mode: ReferenceMode,
    ) -> Result<Self, ControlError> {
        let p64: VehicleParams<f64> = params.cast();
        if !p64.is_valid() || q[(0, 0)] != q[(1, 1)] || q[(3, 3)] != q[(4, 4)] {
            return Err(ControlError::InvalidParameter);
        }
        let k = design_discrete(&quat_hover_model(&p64, 0.0), q, r, ts)?.k;
        Ok(Self {
            bx: params.input_box(),
            vehicle: Vehicle::new(&params),
            gain: k.map(|v| lit::<T>(v)),
            mode,
            obs: AccelObserver::off(),
        })
    }

    /// The thesis weights (Table 4.7), the input weights kept relative to
    /// this vehicle's input ranges ([`inputs_weighted_for`]; the thesis'
    /// own on the OS4).
    pub fn thesis(params: VehicleParams<T>, ts: f64, mode: ReferenceMode) -> Result<Self, ControlError> {
        let (q, r) = quat_weights();
        let r = inputs_weighted_for(&r, &params);
        Self::new(params, &q, &r, ts, mode)
    }

    /// The gain (in heading-frame coordinates).
    pub fn gain(&self) -> &Gain<T> {
        &self.gain
    }

    /// The same with integral action: the disturbance observer `obs`
    /// ([`AccelObserver`]) whose estimate the attitude and thrust targets
    /// cancel.
    pub fn with_observer(mut self, obs: AccelObserver<T>) -> Self {
        self.obs = obs;
        self
    }

    /// The disturbance observer (off for the thesis weights).
    pub fn observer(&self) -> &AccelObserver<T> {
        &self.obs
    }
}

impl<T: RealField + Copy> Controller<T> for LqrQuat<T> {
    fn update(&mut self, est: &StateEstimate<T>, sp: &Setpoint<T>) -> Result<ControlOutput<T>, ControlError> {
        validate(est, sp)?;
        self.obs.observe(est);
        let ar = AttitudeRef::with_disturbance(&self.vehicle.params, sp, self.mode, &self.obs.estimate());
        let frame = HeadingFrame::new(quat_to_euler(&est.att)[2]);
        let qa = frame.attitude(&est.att);
        let qr = frame.attitude(&euler_to_quat(ar.roll_rad, ar.pitch_rad, ar.yaw_rad));
        let mut dx = SVector::<T, 12>::zeros();
        dx.fixed_rows_mut::<3>(0)
            .copy_from(&frame.to_frame(&(est.pos_ned_m - sp.pos_ned_m)));
        dx.fixed_rows_mut::<3>(3)
            .copy_from(&frame.to_frame(&(est.vel_ned_mps - sp.vel_ned_mps)));
        for i in 0..3 {
            dx[6 + i] = qa[1 + i] - qr[1 + i];
        }
        dx.fixed_rows_mut::<3>(9)
            .copy_from(&(est.rates_frd_radps - ar.rates_frd_radps));
        let tff = self.obs.torque_feedforward(&self.vehicle);
        let u_ref = Vector4::new(ar.thrust_n, tff[0], tff[1], tff[2]);
        let raw = u_ref - self.gain * dx;
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
