//! Controllers behind one small interface, selectable at run time
//! (Crazyflie style: one file per controller).
//!
//! Every controller maps a [`StateEstimate`] and a [`Setpoint`] to inputs `U`
//! inside the box of docs/book/src/model.md §2, with a [`ControlStatus`] record. Non-finite
//! inputs are rejected with a [`ControlError`]; the caller keeps flying with
//! its failsafe.

pub mod lqr_euler;
pub mod lqr_quat;
pub mod lqr_table;
pub mod mpc;
pub mod observer;
pub mod pd_euler;
pub mod pd_quat;
pub mod reference;
pub mod regulation;
pub mod spec;
pub mod tuning;

pub use crate::model::AttitudeForm;
pub use lqr_euler::LqrEuler;
pub use lqr_quat::LqrQuat;
pub use lqr_table::GainTable;
pub use mpc::{Mpc, MpcConfig, MpcFast, MpcThesis};
pub use observer::AccelObserver;
pub use pd_euler::{PdAxis, PdEuler, PdEulerGains};
pub use pd_quat::{PdQuat, PdQuatGains};
pub use reference::{tilt_and_thrust, AttitudeRef, ReferenceMode, TiltThrust};
pub use spec::{ControllerSpec, Family, Preset, SpecError, SpecRow, INTEGRAL_MOMENT_TAU_S, INTEGRAL_TAU_S, SPECS};
pub use tuning::{Tuning, WeightScale};

use crate::linalg::RiccatiError;
use crate::model::{quat_to_euler, DiscretiseError, Input, Quat, QuatState};
use nalgebra::{RealField, Vector3};

/// What the controller knows of the vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateEstimate<T: RealField + Copy> {
    /// Position, NED, m.
    pub pos_ned_m: Vector3<T>,
    /// Velocity, NED, m/s.
    pub vel_ned_mps: Vector3<T>,
    /// Attitude, unit quaternion body FRD → NED, scalar first.
    pub att: Quat<T>,
    /// Body rates (p, q, r), FRD, rad/s.
    pub rates_frd_radps: Vector3<T>,
}

impl<T: RealField + Copy> StateEstimate<T> {
    /// From a quaternion-form state vector.
    pub fn from_quat_state(x: &QuatState<T>) -> Self {
        Self {
            pos_ned_m: x.fixed_rows::<3>(0).into_owned(),
            vel_ned_mps: x.fixed_rows::<3>(3).into_owned(),
            att: x.fixed_rows::<4>(6).into_owned(),
            rates_frd_radps: x.fixed_rows::<3>(10).into_owned(),
        }
    }

    /// ZYX Euler angles (φ, θ, ψ), rad.
    pub fn euler(&self) -> Vector3<T> {
        quat_to_euler(&self.att)
    }

    /// True if every value is finite and the attitude is a unit quaternion (±1e-3).
    pub fn is_valid(&self) -> bool {
        let n = crate::math::sqrt(self.att.norm_squared());
        self.pos_ned_m.iter().all(|v| v.is_finite())
            && self.vel_ned_mps.iter().all(|v| v.is_finite())
            && self.rates_frd_radps.iter().all(|v| v.is_finite())
            && n.is_finite()
            && (n - T::one()).abs() < crate::lit(1e-3)
    }
}

/// Where the vehicle should be: position and its first two derivatives, heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setpoint<T: RealField + Copy> {
    /// Position, NED, m.
    pub pos_ned_m: Vector3<T>,
    /// Velocity, NED, m/s (feed-forward; zero for a fixed target).
    pub vel_ned_mps: Vector3<T>,
    /// Acceleration, NED, m/s² (feed-forward; zero for a fixed target).
    pub acc_ned_mps2: Vector3<T>,
    /// Jerk, NED, m/s³ (gives the feed-forward body rates; zero for a fixed target).
    pub jerk_ned_mps3: Vector3<T>,
    /// Heading ψ, rad.
    pub yaw_rad: T,
    /// Heading rate, rad/s.
    pub yaw_rate_radps: T,
}

impl<T: RealField + Copy> Setpoint<T> {
    /// Hold a position and heading.
    pub fn hold(pos_ned_m: Vector3<T>, yaw_rad: T) -> Self {
        Self {
            pos_ned_m,
            vel_ned_mps: Vector3::zeros(),
            acc_ned_mps2: Vector3::zeros(),
            jerk_ned_mps3: Vector3::zeros(),
            yaw_rad,
            yaw_rate_radps: T::zero(),
        }
    }

    /// The setpoint `t` seconds ahead along its own derivatives (constant
    /// jerk and heading rate): what a controller assumes without a preview.
    pub fn extrapolate(&self, t: T) -> Self {
        let half = crate::lit::<T>(0.5);
        let sixth = crate::lit::<T>(1.0 / 6.0);
        Self {
            pos_ned_m: self.pos_ned_m
                + self.vel_ned_mps * t
                + self.acc_ned_mps2 * (half * t * t)
                + self.jerk_ned_mps3 * (sixth * t * t * t),
            vel_ned_mps: self.vel_ned_mps + self.acc_ned_mps2 * t + self.jerk_ned_mps3 * (half * t * t),
            acc_ned_mps2: self.acc_ned_mps2 + self.jerk_ned_mps3 * t,
            jerk_ned_mps3: self.jerk_ned_mps3,
            yaw_rad: self.yaw_rad + self.yaw_rate_radps * t,
            yaw_rate_radps: self.yaw_rate_radps,
        }
    }

    /// True if every value is finite.
    pub fn is_valid(&self) -> bool {
        self.pos_ned_m.iter().all(|v| v.is_finite())
            && self.vel_ned_mps.iter().all(|v| v.is_finite())
            && self.acc_ned_mps2.iter().all(|v| v.is_finite())
            && self.jerk_ned_mps3.iter().all(|v| v.is_finite())
            && self.yaw_rad.is_finite()
            && self.yaw_rate_radps.is_finite()
    }
}

/// What a controller reports with each output.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ControlStatus {
    /// The unconstrained law left the input box and was clamped this step.
    pub saturated: bool,
    /// Largest excursion of the unconstrained law outside the box (own units).
    pub excursion: f32,
    /// Optimiser iterations this step (0 for explicit laws).
    pub iterations: u16,
}

/// One controller step's result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlOutput<T: RealField + Copy> {
    /// Inputs `[U1 N, U2 N, U3 N, U4 N·m]`, always inside the box.
    pub u: Input<T>,
    /// Diagnostics.
    pub status: ControlStatus,
}

/// Why a controller could not produce an output or be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ControlError {
    /// The state estimate had NaN/∞ or a non-unit quaternion.
    InvalidEstimate,
    /// The setpoint had NaN/∞.
    InvalidSetpoint,
    /// A gain design step failed (Riccati).
    Riccati(RiccatiError),
    /// A discretisation failed.
    Discretise(DiscretiseError),
    /// A parameter (sample time, gains, vehicle) was out of range.
    InvalidParameter,
}

impl core::fmt::Display for ControlError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ControlError::InvalidEstimate => {
                f.write_str("state estimate has NaN/inf or a non-unit attitude quaternion")
            }
            ControlError::InvalidSetpoint => f.write_str("setpoint has NaN/inf"),
            ControlError::Riccati(e) => write!(f, "gain design failed: {e}"),
            ControlError::Discretise(e) => write!(f, "discretisation failed: {e}"),
            ControlError::InvalidParameter => {
                f.write_str("a parameter (sample time, gains, vehicle, preview index) is out of range")
            }
        }
    }
}

impl core::error::Error for ControlError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            ControlError::Riccati(e) => Some(e),
            ControlError::Discretise(e) => Some(e),
            _ => None,
        }
    }
}

impl From<RiccatiError> for ControlError {
    fn from(e: RiccatiError) -> Self {
        ControlError::Riccati(e)
    }
}

impl From<DiscretiseError> for ControlError {
    fn from(e: DiscretiseError) -> Self {
        ControlError::Discretise(e)
    }
}

/// The interface every controller implements.
pub trait Controller<T: RealField + Copy> {
    /// One control step: inputs for the current estimate and setpoint.
    fn update(&mut self, est: &StateEstimate<T>, sp: &Setpoint<T>) -> Result<ControlOutput<T>, ControlError>;
    /// Forgets internal state (warm starts, estimates) before a new flight.
    fn reset(&mut self);
    /// The next `update` does not follow the last one by one period (sensor
    /// data were missing or invalid, e.g. a failsafe episode): forget what
    /// ties one step to the step before, keep what is still true of the
    /// vehicle and its surroundings. The default keeps everything (a
    /// controller without memory). The MPC drops its previous state (its
    /// disturbance observer would otherwise read the whole gap as one
    /// step's innovation) and keeps its disturbance estimate and trend,
    /// warm start, previous input and preview.
    fn resume(&mut self) {}
    /// The measured time since the previous `update`, s, for the next
    /// `update` only: a simulator stepping at 2 or 3 ms, a late sample or an
    /// uneven grid. Controllers whose memory spans a step (the disturbance
    /// observers) integrate over it instead of their nominal period, so an
    /// uneven step is not read as a disturbance. A value that is not a
    /// plausible step ([`plausible_step`]) is ignored: that update uses the
    /// nominal period. The default ignores it (a controller without memory).
    fn elapsed(&mut self, _dt_s: T) {}
    /// Reference preview wanted before each update: `(steps, spacing s)`;
    /// `None` for controllers that use only the current setpoint.
    fn preview_request(&self) -> Option<(usize, f64)> {
        None
    }
    /// Gives the setpoint `k` preview steps ahead (1-based).
    fn set_preview(&mut self, _k: usize, _sp: &Setpoint<T>) -> Result<(), ControlError> {
        Err(ControlError::InvalidParameter)
    }
    /// The preview given last began `age_s` ago: the next update uses it,
    /// moved on by that long ([`crate::control::mpc::Mpc::age_preview`]).
    fn age_preview(&mut self, _age_s: T) -> Result<(), ControlError> {
        Err(ControlError::InvalidParameter)
    }
    /// Moves the preview on one step, `sp` its new last
    /// ([`crate::control::mpc::Mpc::roll_preview`]).
    fn roll_preview(&mut self, _sp: &Setpoint<T>) -> Result<(), ControlError> {
        Err(ControlError::InvalidParameter)
    }
    /// The period this controller is designed to run at, s (`None`: any).
    fn period_s(&self) -> Option<f64> {
        None
    }
    /// The a-priori cap on iterative work per step (QP iterations for an
    /// MPC); 0 for controllers without iterations.
    fn iteration_bound(&self) -> u32 {
        0
    }
}

/// Longest interval between two updates that a controller's memory
/// integrates over, s: longer is a gap, after which the caller resumes the
/// controller ([`Controller::resume`]) instead. 20 ms: a 50 Hz simulator's
/// step, or 20 lost 1 kHz samples.
pub const MAX_STEP_S: f64 = 0.02;

/// Whether `dt_s` is an interval a controller integrates over: positive,
/// finite and at most [`MAX_STEP_S`] or 1.5 × its nominal `period_s` (s;
/// the thesis MPC steps every 250 ms by design).
pub fn plausible_step<T: RealField + Copy>(dt_s: T, period_s: f64) -> bool {
    let max = crate::lit::<T>(MAX_STEP_S.max(1.5 * period_s));
    dt_s.is_finite() && dt_s > T::zero() && dt_s <= max
}

/// Tells `ctrl` the `dt_us` µs since its last update
/// ([`Controller::elapsed`]), or resumes it ([`Controller::resume`]) when
/// that interval is a gap for a controller of nominal period `period_s`
/// ([`plausible_step`]). The one rule of the flight loop on the MCU and of
/// the SIL, so that both hand the controller the same numbers.
pub fn tell_interval<C: Controller<f32> + ?Sized>(ctrl: &mut C, dt_us: u64, period_s: f64) {
    if plausible_step(dt_us as f64 * 1e-6, period_s) {
        ctrl.elapsed(dt_us as f32 * 1e-6);
    } else {
        ctrl.resume();
    }
}

/// Checks both inputs of a step.
pub(crate) fn validate<T: RealField + Copy>(est: &StateEstimate<T>, sp: &Setpoint<T>) -> Result<(), ControlError> {
    if !est.is_valid() {
        return Err(ControlError::InvalidEstimate);
    }
    if !sp.is_valid() {
        return Err(ControlError::InvalidSetpoint);
    }
    Ok(())
}

/// Clamps the raw law into the box and fills the status.
pub(crate) fn saturate<T: RealField + Copy>(bx: &crate::model::InputBox<T>, raw: &Input<T>) -> ControlOutput<T> {
    let u = bx.clamp(raw);
    let exc = bx.violation(raw);
    let excursion = nalgebra::try_convert::<T, f64>(exc).unwrap_or(f64::INFINITY) as f32;
    ControlOutput {
        u,
        status: ControlStatus {
            saturated: exc > T::zero(),
            excursion,
            iterations: 0,
        },
    }
}

/// The frame of a heading ψ: NED turned by ψ about down. The hover models
/// linearised at ψT = 0 hold in it for any heading (the dynamics are
/// yaw-symmetric), which is how the quaternion LQR and the MPC avoid
/// heading-dependent models.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadingFrame<T: RealField + Copy> {
    s: T,
    c: T,
    /// The heading quaternion `(cos ψ/2, 0, 0, sin ψ/2)`.
    q: Quat<T>,
}

impl<T: RealField + Copy> HeadingFrame<T> {
    /// The frame of heading `yaw` (rad).
    pub fn new(yaw: T) -> Self {
        let (s, c) = crate::math::sin_cos(yaw);
        let (sh, ch) = crate::math::sin_cos(yaw * crate::lit::<T>(0.5));
        let q = nalgebra::Vector4::new(ch, T::zero(), T::zero(), sh);
        Self { s, c, q }
    }

    /// An NED vector in this frame (turned by −ψ).
    pub fn to_frame(&self, v: &Vector3<T>) -> Vector3<T> {
        Vector3::new(self.c * v[0] + self.s * v[1], -self.s * v[0] + self.c * v[1], v[2])
    }

    /// A vector of this frame back in NED (turned by +ψ).
    pub fn to_ned(&self, v: &Vector3<T>) -> Vector3<T> {
        Vector3::new(self.c * v[0] - self.s * v[1], self.s * v[0] + self.c * v[1], v[2])
    }

    /// The attitude `q` (body → NED) relative to this frame, `q_h⁻¹ ⊗ q`, on
    /// the `q0 ≥ 0` hemisphere (shortest way round).
    pub fn attitude(&self, q: &Quat<T>) -> Quat<T> {
        let r = crate::model::quat_mul(&crate::model::quat_conj(&self.q), q);
        if r[0] < T::zero() {
            -r
        } else {
            r
        }
    }
}

/// Wraps an angle to (−π, π].
pub fn wrap_pi<T: RealField + Copy>(a: T) -> T {
    let two_pi = T::two_pi();
    // `%` is a call into `fmod` (a loop over the exponent difference on the
    // M4); within one turn it is the identity, so it is skipped there.
    let mut x = if a.abs() < two_pi { a } else { a % two_pi };
    if x > T::pi() {
        x -= two_pi;
    } else if x <= -T::pi() {
        x += two_pi;
    }
    x
}

/// Any controller, dispatched at run time without allocation.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum AnyController<T: RealField + Copy> {
    /// See [`PdEuler`].
    PdEuler(PdEuler<T>),
    /// See [`PdQuat`].
    PdQuat(PdQuat<T>),
    /// See [`LqrEuler`].
    LqrEuler(LqrEuler<T>),
    /// See [`LqrQuat`].
    LqrQuat(LqrQuat<T>),
    /// See [`Mpc`] (`thesis` preset sizes).
    MpcThesis(MpcThesis<T>),
    /// See [`Mpc`] (`fast` preset sizes).
    MpcFast(MpcFast<T>),
}

// Switching the variant of a slot: each in its own out-of-line function, so
// that the blank controller's temporary (≈ 7 KiB) lives in a frame that is
// gone before the design (which runs in the slot) starts.
impl<T: RealField + Copy> AnyController<T> {
    /// Makes the slot an Euler PD with `gains`.
    #[inline(never)]
    pub(crate) fn become_pdeuler(
        &mut self,
        p: crate::model::VehicleParams<T>,
        gains: PdEulerGains<T>,
        mode: ReferenceMode,
        obs: AccelObserver<T>,
    ) {
        *self = AnyController::PdEuler(PdEuler::new(p, gains, mode).with_observer(obs));
    }

    /// Makes the slot a quaternion PD with `gains`.
    #[inline(never)]
    pub(crate) fn become_pdquat(
        &mut self,
        p: crate::model::VehicleParams<T>,
        gains: PdQuatGains<T>,
        mode: ReferenceMode,
        obs: AccelObserver<T>,
    ) {
        *self = AnyController::PdQuat(PdQuat::new(p, gains, mode).with_observer(obs));
    }

    /// Makes the slot the (small, already designed) quaternion LQR `c`.
    #[inline(never)]
    pub(crate) fn become_lqrquat(&mut self, c: LqrQuat<T>) {
        *self = AnyController::LqrQuat(c);
    }

    /// Makes the slot a blank scheduled Euler LQR (see [`LqrEuler::blank`]).
    #[inline(never)]
    pub(crate) fn become_lqreuler(&mut self, p: crate::model::VehicleParams<T>, mode: ReferenceMode) {
        *self = AnyController::LqrEuler(LqrEuler::blank(p, mode));
    }

    /// Makes the slot a blank `fast`-sized MPC (see [`Mpc::blank`]).
    #[inline(never)]
    pub(crate) fn become_mpcfast(&mut self, p: crate::model::VehicleParams<T>, cfg: MpcConfig) {
        *self = AnyController::MpcFast(MpcFast::blank(p, cfg));
    }

    /// Makes the slot a blank `thesis`-sized MPC (see [`Mpc::blank`]).
    #[inline(never)]
    pub(crate) fn become_mpcthesis(&mut self, p: crate::model::VehicleParams<T>, cfg: MpcConfig) {
        *self = AnyController::MpcThesis(MpcThesis::blank(p, cfg));
    }
}

impl<T: RealField + Copy> Controller<T> for AnyController<T> {
    fn update(&mut self, est: &StateEstimate<T>, sp: &Setpoint<T>) -> Result<ControlOutput<T>, ControlError> {
        match self {
            AnyController::PdEuler(c) => c.update(est, sp),
            AnyController::PdQuat(c) => c.update(est, sp),
            AnyController::LqrEuler(c) => c.update(est, sp),
            AnyController::LqrQuat(c) => c.update(est, sp),
            AnyController::MpcThesis(c) => c.update(est, sp),
            AnyController::MpcFast(c) => c.update(est, sp),
        }
    }
    fn resume(&mut self) {
        match self {
            AnyController::PdEuler(c) => c.resume(),
            AnyController::PdQuat(c) => c.resume(),
            AnyController::LqrEuler(c) => c.resume(),
            AnyController::LqrQuat(c) => c.resume(),
            AnyController::MpcThesis(c) => c.resume(),
            AnyController::MpcFast(c) => c.resume(),
        }
    }
    fn elapsed(&mut self, dt_s: T) {
        match self {
            AnyController::PdEuler(c) => c.elapsed(dt_s),
            AnyController::PdQuat(c) => c.elapsed(dt_s),
            AnyController::LqrEuler(c) => c.elapsed(dt_s),
            AnyController::LqrQuat(c) => c.elapsed(dt_s),
            AnyController::MpcThesis(c) => c.elapsed(dt_s),
            AnyController::MpcFast(c) => c.elapsed(dt_s),
        }
    }
    fn reset(&mut self) {
        match self {
            AnyController::PdEuler(c) => c.reset(),
            AnyController::PdQuat(c) => c.reset(),
            AnyController::LqrEuler(c) => c.reset(),
            AnyController::LqrQuat(c) => c.reset(),
            AnyController::MpcThesis(c) => c.reset(),
            AnyController::MpcFast(c) => c.reset(),
        }
    }
    fn preview_request(&self) -> Option<(usize, f64)> {
        match self {
            AnyController::MpcThesis(c) => c.preview_request(),
            AnyController::MpcFast(c) => c.preview_request(),
            _ => None,
        }
    }
    fn set_preview(&mut self, k: usize, sp: &Setpoint<T>) -> Result<(), ControlError> {
        match self {
            AnyController::MpcThesis(c) => c.set_preview(k, sp),
            AnyController::MpcFast(c) => c.set_preview(k, sp),
            _ => Err(ControlError::InvalidParameter),
        }
    }
    fn age_preview(&mut self, age_s: T) -> Result<(), ControlError> {
        match self {
            AnyController::MpcThesis(c) => c.age_preview(age_s),
            AnyController::MpcFast(c) => c.age_preview(age_s),
            _ => Err(ControlError::InvalidParameter),
        }
    }
    fn roll_preview(&mut self, sp: &Setpoint<T>) -> Result<(), ControlError> {
        match self {
            AnyController::MpcThesis(c) => c.roll_preview(sp),
            AnyController::MpcFast(c) => c.roll_preview(sp),
            _ => Err(ControlError::InvalidParameter),
        }
    }
    fn period_s(&self) -> Option<f64> {
        match self {
            AnyController::MpcThesis(c) => c.period_s(),
            AnyController::MpcFast(c) => c.period_s(),
            _ => None,
        }
    }
    fn iteration_bound(&self) -> u32 {
        match self {
            AnyController::MpcThesis(c) => Controller::iteration_bound(c),
            AnyController::MpcFast(c) => Controller::iteration_bound(c),
            _ => 0,
        }
    }
}
