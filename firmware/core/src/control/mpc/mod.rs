//! Linear MPC about hover (thesis 3.101–3.116, Appendix C), Euler and
//! quaternion form, solved each step by the core's box-constrained QP solver.
//!
//! - **Model**: the hover model at ψT = 0, used in the frame of the current
//!   heading (position and velocity rotated by −ψ, attitude relative to the
//!   heading). The dynamics are yaw-symmetric and the weights treat x and y
//!   alike, so this is the thesis' heading-scheduled model, exactly, with a
//!   Hessian that never changes: its eigenvalues and the QP's iteration bound
//!   are computed once.
//! - **Prediction**: `N` steps of `pred_dt` (exact ZOH), inputs moved at the
//!   first `M` steps and held afterwards (control horizon / move blocking),
//!   re-solved every `exec_dt` (the two may differ).
//! - **Cost**: `½Σ(x_k − r_k)ᵀQ(x_k − r_k) + ½Σ(u_k − u_ref,k)ᵀR(u_k − u_ref,k) +
//!   ½ΣΔu_kᵀSΔu_k`, optional terminal weight from the DARE. In the
//!   quaternion form the attitude part of `x − r` is the error quaternion's
//!   vector part; about hover in the heading frame it equals the component
//!   difference to first order (that is what a linear MPC can carry), and the
//!   current heading error is the exact error quaternion, shortest way round.
//! - **Reference preview**: the `N` future setpoints (supplied by the caller,
//!   or extrapolated from the current one when absent), each with the attitude,
//!   thrust and rates its acceleration implies.
//! - **Offset-free**: an observer for constant force (NED) and moment (body)
//!   disturbances, fed into the prediction (the thesis' MATLAB MPC used an
//!   output-disturbance estimator for the same reason); optionally a damped
//!   trend of the horizontal force over the horizon, so a gust is anticipated
//!   rather than chased.
//! - **Rotors** (optional, [`MpcConfig::rotor_lag_prediction`]): the four
//!   inputs reach the vehicle through the rotors' first-order lag, four more
//!   states of the prediction (16 in all).
//! - **Gradient by adjoint recursion**, channel by channel: the model
//!   couples no two of its four input channels, so it is stored and run as
//!   four blocks of 3, 5, 5 and 3 states ([`CHANNELS`]) and no prediction
//!   matrix is stored.

use super::reference::AttitudeRef;
use super::{
    validate, wrap_pi, ControlError, ControlOutput, ControlStatus, Controller, HeadingFrame, ReferenceMode, Setpoint,
    StateEstimate,
};
use crate::linalg::matvec::mul;
use crate::linalg::solve_dare;
use crate::lit;
use crate::model::{
    euler_hover_model, quat_hover_model, quat_to_euler, zoh_into, AttitudeForm, InputBox, LinearModel, VehicleParams,
};
use crate::qp::{BoxQp, QpSettings, QpSolution};
use nalgebra::{RealField, SMatrix, SVector, Vector3, Vector4};

mod design;
mod gradient;

use design::qp_settings;

/// Everything that defines an MPC besides its sizes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpcConfig {
    /// Attitude coordinates.
    pub form: AttitudeForm,
    /// Prediction step, s.
    pub pred_dt_s: f64,
    /// Execution period (how often the QP is re-solved), s.
    pub exec_dt_s: f64,
    /// Stage state weights (diagonal), in the form's coordinates.
    pub q: [f64; 12],
    /// Input weights on `U − U_ref` (diagonal).
    pub r: [f64; 4],
    /// Input-rate weights on `U_k − U_{k−1}` per prediction step (diagonal).
    pub s: [f64; 4],
    /// Terminal weight from the DARE of (Q, R) instead of Q at the last step.
    pub terminal: bool,
    /// Time constant of the disturbance observer's force part, s (`None`:
    /// no estimate, neither force nor moment).
    pub observer_tau_s: Option<f64>,
    /// Time constant of its moment part, s (used when `observer_tau_s` is
    /// set; at most one execution period means the estimate is the last
    /// step's whole rate innovation). Without
    /// [`observer_rotor_lag`](Self::observer_rotor_lag) the torque the rotors
    /// have not yet delivered shows up as a moment "disturbance" and is asked
    /// for again on the next step; with it, the estimate holds what the lag
    /// model leaves out (a rotor slower or faster than the vehicle's own).
    pub observer_moment_tau_s: f64,
    /// The observer compares the vehicle with the thrust and yaw torque its
    /// rotors have delivered (a first-order lag of the input sent, the
    /// vehicle's `rotor_tau_s`), not with the input sent. Compared with the
    /// input sent, the thrust and torque not yet delivered read as a
    /// disturbance and are asked for again: positive feedback around the
    /// lag, which amplifies the MPC's own commands near `1/√(τ·τ_rotor)`
    /// and, with a 72 ms rotor, set up a limit cycle that swung the motors
    /// from zero to full speed (docs/book/src/mpc.md). Roll and pitch keep
    /// the input sent: there the fast moment estimate's re-asking makes up
    /// for slow rotors, which the robustness sweep and gust rejection on a
    /// plant without lag rely on (the heavy roll/pitch-rate weights keep
    /// that loop damped).
    pub observer_rotor_lag: bool,
    /// The prediction models the rotors: each input reaches the vehicle
    /// through a first-order lag with the vehicle's `rotor_tau_s`, as four
    /// more states of the model the MPC predicts with (the thrust and the
    /// three torques the rotors deliver, `U_d − U_hover`; N, N·m), started
    /// each step from what the lag model says the rotors deliver now. The
    /// prediction then knows that a thrust or torque asked for arrives
    /// over `τr`, not at once, so the attitude loop needs no heavy rate
    /// weights to stay damped under slow rotors. With it the observer
    /// compares the vehicle with what the rotors deliver on every axis
    /// (roll and pitch too). `false`: the lag states stay zero and the
    /// prediction is the rotor-less hover model.
    pub rotor_lag_prediction: bool,
    /// Prediction steps each move but the last spans (≥ 1; the last move is
    /// held over the rest of the horizon, so `(M − 1)·move_steps < N`).
    /// Move blocking: with the rotors in the prediction, two moves one
    /// 50 ms step apart behind a 178 ms lag are nearly one move to the
    /// prediction, and the QP's Hessian nearly singular in their direction
    /// (the strong-convexity certificate alone then fails to prove its
    /// accuracy; the blocks' duality gap proves it); moves two steps apart
    /// are not.
    pub move_steps: usize,
    /// Damped-trend prediction of the horizontal disturbance force: its
    /// horizon `T`, s (`None`: the estimate is held constant over the
    /// prediction). The estimate's rate ḋ is extrapolated as
    /// `d(τ) = d̂ + ḋ·T·(1 − e^(−τ/T))`: a gust is followed about `T` ahead
    /// and never extrapolated without bound.
    pub disturbance_trend_s: Option<f64>,
    /// Largest extrapolated change `|ḋ|·T` of the horizontal disturbance
    /// acceleration, m/s² (bounds the trend during manoeuvres, when model
    /// error, not wind, moves the estimate).
    pub disturbance_trend_max_mps2: f64,
    /// Time constant τ of the rate filter `s/(τs + 1)²` that gives ḋ from the
    /// estimate, s (> the execution period): shorter follows a gust with less
    /// lag, longer passes less sensor noise.
    pub disturbance_rate_filter_s: f64,
    /// Reference feed-forward.
    pub reference: ReferenceMode,
    /// Largest heading error the reference may ask for, rad. The prediction
    /// holds the heading frame fixed over the horizon; a turn much faster than
    /// the position dynamics rotates the position feedback by up to 90°+ within
    /// one horizon and destabilises a combined turn-and-translate. Capping the
    /// error turns at a bounded rate instead (π: no cap).
    pub max_heading_error_rad: f64,
    /// Largest distance between the vehicle and the reference position
    /// the prediction starts from, m (`f64::INFINITY`: no cap). A farther
    /// reference is moved, whole horizon alike, towards the vehicle until
    /// its first step is this far: the prediction is linear about hover,
    /// and a target metres away asks for a tilt the linear model does not
    /// hold (a 4.9 m target at −120° under the 0.178 s rotors of
    /// `mismatch` saturated every torque from the first step and tumbled).
    /// The reference's velocity and acceleration are kept, so a trajectory
    /// is still followed, only from nearer.
    pub max_position_error_m: f64,
    /// Stop each QP as soon as its accuracy is proved (`false`: run the
    /// a-priori bound every time, a fixed-time solve).
    pub qp_early_exit: bool,
    /// QP objective accuracy every solve proves (the objective's units; see
    /// [`crate::qp`]).
    pub qp_accuracy: f64,
    /// Cap on QP iterations. At or above the a-priori bound
    /// ([`Mpc::iteration_bound`]) every solve is certified; below it a solve
    /// may stop unproved ([`crate::qp::QpStatus::IterationLimit`]).
    pub qp_max_iterations: u32,
    /// Solve the QP exactly by enumerating the active sets of its
    /// independent blocks when its Hessian has them
    /// ([`crate::qp::QpSettings::enumerate`]); `false`: the fast gradient
    /// method with its certified iteration bound.
    pub qp_enumerate: bool,
}

impl MpcConfig {
    /// Thesis preset (Appendix C): Ts = 0.25 s prediction and execution, N = 20,
    /// M = 2; MATLAB's weights squared: 25 on x, y, z (and on the heading, which
    /// the thesis' ψ settling time shows it weighted), 0.01 on every input rate,
    /// 0.25 on U4; no terminal weight; disturbance estimate on.
    pub fn thesis(form: AttitudeForm) -> Self {
        let yaw_w = match form {
            AttitudeForm::Euler => 25.0,
            AttitudeForm::Quaternion => 100.0, // q3 ≈ ψ/2
        };
        Self {
            form,
            pred_dt_s: 0.25,
            exec_dt_s: 0.25,
            q: [25.0, 25.0, 25.0, 0.0, 0.0, 0.0, 0.0, 0.0, yaw_w, 0.0, 0.0, 0.0],
            r: [0.0, 0.0, 0.0, 0.25],
            s: [0.01; 4],
            terminal: false,
            observer_tau_s: Some(0.5),
            observer_moment_tau_s: 0.5,
            observer_rotor_lag: false,
            rotor_lag_prediction: false,
            move_steps: 1,
            disturbance_trend_s: None,
            disturbance_trend_max_mps2: 0.0,
            disturbance_rate_filter_s: 0.1,
            reference: ReferenceMode::Thesis,
            max_heading_error_rad: core::f64::consts::PI,
            max_position_error_m: f64::INFINITY,
            qp_early_exit: true,
            qp_accuracy: 1e-6,
            qp_max_iterations: 2000,
            qp_enumerate: true,
        }
    }

    /// The project's preset: 50 ms prediction steps over a 1 s horizon,
    /// re-solved at 1 kHz (every IMU sample), full-state weights, DARE
    /// terminal weight, feed-forward of the previewed reference, disturbance
    /// estimate, the rotors' lag in the prediction; with [`MpcFast`]'s three
    /// moves (the first two two prediction steps long, then one held for
    /// the rest of the horizon).
    ///
    /// Three moves, not four: the QP has 12 variables instead of 16 (four
    /// independent blocks of 3, solved exactly by trying their 27 active
    /// sets each; four moves would be 81 each). The whole image step (IMU
    /// sample, estimator with a fix, this MPC, output) is measured in QEMU
    /// against its budget (`src/bin/budget/main.rs`, docs/book/src/firmware.md).
    ///
    /// Tuning (docs/book/src/mpc.md): position weights 800 (z 120) and
    /// velocity weights 20 (z 8) for tracking. The rotors' lag is in the
    /// prediction ([`MpcConfig::rotor_lag_prediction`], the vehicle's
    /// `rotor_tau_s`), so the attitude loop needs no damping from the
    /// weights: the roll/pitch-rate weights are 1.8 (blind to the rotors
    /// the preset needed 600, and 0.2 diverged under `mismatch`'s 0.178 s
    /// lag). Moves two prediction steps long: behind the lag, two moves
    /// 50 ms apart are nearly one. The reference is kept within 2.5 m of
    /// the vehicle ([`MpcConfig::max_position_error_m`]): the study's far
    /// target (4.9 m at −120°) asked a lightly damped linear model for
    /// more tilt than it holds. The horizontal disturbance is predicted
    /// with a damped trend (T = 0.3 s, rate through `s/(τs + 1)²` with
    /// τ = 50 ms, at most 0.4 m/s² of extrapolated change): a 0.5 Hz gust
    /// moves through half its swing within the 1 s horizon. The moment
    /// estimate has τ = 10 ms: with the lag in the prediction the observer
    /// compares roll and pitch with the torque the rotors delivered, and
    /// at 4 ms (the lag-blind preset's) the set-point under `wind` stepped
    /// every 3 ms departed 11 cm from the one stepped every 1 ms, against
    /// 4 mm at 10 ms (`fast_mpc_flies_the_same_on_any_simulator_grid`
    /// holds 2 cm).
    /// The f32 QP's certificate proves its 1e-5 with these weights through
    /// the blocks' duality gap (`qp::tests`).
    pub fn fast(form: AttitudeForm) -> Self {
        let a = match form {
            AttitudeForm::Euler => 1.0,
            AttitudeForm::Quaternion => 4.0, // half-angles
        };
        Self {
            form,
            pred_dt_s: 0.05,
            exec_dt_s: 0.001,
            q: [
                800.0,
                800.0,
                120.0,
                20.0,
                20.0,
                8.0,
                30.0 * a,
                30.0 * a,
                20.0 * a,
                1.8,
                1.8,
                5.0,
            ],
            r: [0.5, 2.0, 2.0, 20.0],
            s: [0.05, 0.5, 0.5, 5.0],
            terminal: true,
            observer_tau_s: Some(0.02),
            observer_moment_tau_s: 0.01,
            observer_rotor_lag: true,
            rotor_lag_prediction: true,
            move_steps: 2,
            disturbance_trend_s: Some(0.3),
            disturbance_trend_max_mps2: 0.4,
            disturbance_rate_filter_s: 0.05,
            reference: ReferenceMode::Feedforward,
            max_heading_error_rad: 0.35,
            max_position_error_m: 2.5,
            qp_early_exit: true,
            qp_accuracy: 1e-5,
            // With `qp_enumerate = false` (the iterative solver): no cap,
            // every solve stops as soon as its accuracy is proved, at worst
            // at the a-priori bound (260 iterations with M = 3).
            qp_max_iterations: u32::MAX,
            qp_enumerate: true,
        }
    }
}

/// The QP the MPC solved last: `min ½zᵀHz + gᵀz, lb ≤ z ≤ ub` (H is
/// [`Mpc::hessian`]), z = the `M` moves of `U − U_hover`, 4 per move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpcQp<T: RealField + Copy, const NZ: usize> {
    /// Linear term.
    pub g: SVector<T, NZ>,
    /// Lower bounds.
    pub lb: SVector<T, NZ>,
    /// Upper bounds.
    pub ub: SVector<T, NZ>,
    /// The solve's warm start.
    pub warm: SVector<T, NZ>,
    /// The solver's answer.
    pub solution: QpSolution<T, NZ>,
}

type Vec12<T> = SVector<T, 12>;
/// States of the prediction model: the hover model's 12
/// (`[x y z ẋ ẏ ż a₁ a₂ a₃ p q r]`) and the four inputs the rotors deliver
/// (`U_d − U_hover`: thrust, N, then roll, pitch and yaw torque, N·m), the
/// states of their first-order lag ([`MpcConfig::rotor_lag_prediction`]).
pub const PREDICTION_STATES: usize = 16;
#[cfg(test)]
type MatX<T> = SMatrix<T, PREDICTION_STATES, PREDICTION_STATES>;
type VecX<T> = SVector<T, PREDICTION_STATES>;
/// The observer's rows of the hover model: the velocity and rate states
/// (`ẋ ẏ ż p q r`), the only ones whose innovation it reads.
const OBSERVED_ROWS: [usize; 6] = [3, 4, 5, 9, 10, 11];

/// Linear MPC with horizon `N` prediction steps, `M` moves and `NZ = 4·M`
/// decision variables.
///
/// ```
/// use fc_core::control::{Controller, MpcConfig, MpcFast, Setpoint, StateEstimate};
/// use fc_core::model::{AttitudeForm, VehicleParams};
/// use nalgebra::{Vector3, Vector4};
///
/// let params = VehicleParams::<f32>::os4();
/// let mut mpc = MpcFast::new(params, MpcConfig::fast(AttitudeForm::Euler))?;
/// // The reference 1 s ahead, one point per prediction step (50 ms): a
/// // climb from 1 m to 2 m (NED z from −1 to −2).
/// let (n, pred_dt) = mpc.preview_request().expect("the MPC asks for a preview");
/// for k in 1..=n {
///     let z = -1.0 - (k as f32 * pred_dt as f32).min(1.0);
///     mpc.set_preview(k, &Setpoint::hold(Vector3::new(0.0, 0.0, z), 0.0))?;
/// }
/// let est = StateEstimate {
///     pos_ned_m: Vector3::new(0.0, 0.0, -1.0),
///     vel_ned_mps: Vector3::zeros(),
///     att: Vector4::new(1.0, 0.0, 0.0, 0.0),
///     rates_frd_radps: Vector3::zeros(),
/// };
/// let out = mpc.update(&est, &Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0))?;
/// assert!(out.u[0] > params.hover_thrust_n()); // it starts climbing before the setpoint moves
/// // The QP it solved: exactly, by enumerating the active sets of its four
/// // independent input channels; the answer inside the input box.
/// use fc_core::qp::QpStatus;
/// let qp = mpc.last_qp().expect("a QP was solved");
/// assert_eq!(qp.solution.status, QpStatus::Exact);
/// assert!(qp.solution.gap <= 1e-5); // its certificate, in the objective's units
/// assert!((0..12).all(|i| qp.lb[i] <= qp.solution.z[i] && qp.solution.z[i] <= qp.ub[i]));
/// # Ok::<(), fc_core::control::ControlError>(())
/// ```
#[derive(Debug, Clone)]
pub struct Mpc<T: RealField + Copy, const N: usize, const M: usize, const NZ: usize> {
    cfg: MpcConfig,
    params: VehicleParams<T>,
    bx: InputBox<T>,
    u_hover: Vector4<T>,
    // Prediction model (pred_dt, with the rotors' lag states), channel by
    // channel ([`CHANNELS`]: thrust, roll, pitch, yaw), and its disturbance
    // input; the observer's rows of the hover model (exec_dt,
    // `OBSERVED_ROWS`). Heading frame.
    zc: Channel<T, 3, M>,
    yc: Channel<T, 5, M>,
    xc: Channel<T, 5, M>,
    wc: Channel<T, 3, M>,
    wd: SMatrix<T, 12, 6>,
    ad_e: SMatrix<T, 6, 12>,
    bd_e: SMatrix<T, 6, 4>,
    wd_e: SMatrix<T, 6, 6>,
    q: Vec12<T>,
    /// The state cost's gradient in z is linear in the initial state, the
    /// disturbance and its trend: `g = Gx·x₀ + Gw·d + Gt·ḋ + (reference
    /// part)`. These are computed once at design ([`Mpc::design_response`]),
    /// so a step needs no free-response simulation, only the adjoint pass
    /// over the references. `Gx` is each channel's own (`Channel::gx`).
    /// Gradient per unit of disturbance (heading frame: acceleration, m/s²,
    /// then angular acceleration, rad/s²).
    gw: SMatrix<T, NZ, 6>,
    /// Gradient per unit of the horizontal disturbance's rate (heading
    /// frame, m/s³), through the damped trend.
    gt: SMatrix<T, NZ, 3>,
    r: Vector4<T>,
    s: Vector4<T>,
    qp: BoxQp<T, NZ>,
    lb: SVector<T, NZ>,
    ub: SVector<T, NZ>,
    settings: QpSettings<T>,
    iteration_bound: u32,
    /// The move of each prediction step ([`MpcConfig::move_steps`]).
    move_of: [u8; N],
    // Run-time state.
    /// The preview, a ring: step `k` (1-based) is at `preview_head + k − 1`
    /// (mod `N`); [`Mpc::roll_preview`] moves it on one step.
    preview: [Setpoint<T>; N],
    preview_head: usize,
    /// The preview is complete.
    preview_valid: bool,
    /// The preview in force is used by the next update: completed or aged
    /// ([`Mpc::age_preview`]) since the last one.
    preview_fresh: bool,
    /// How long ago the preview began, s: its step `k` is the reference at
    /// `k·pred_dt` after that, extrapolated to now.
    preview_age: T,
    z: SVector<T, NZ>,
    du_prev: Vector4<T>,
    /// The input deviation the rotors have delivered by the lag model
    /// ([`MpcConfig::observer_rotor_lag`], [`MpcConfig::rotor_lag_prediction`]):
    /// after a step's observer update, what they deliver now.
    du_delivered: Vector4<T>,
    /// `(dt, e^(−dt/τr), (1 − e^(−dt/τr))·τr/dt)` of the last step, those
    /// of the nominal period after a design or a reset: a loop on a steady
    /// period computes the exponential in the design, not in a step.
    lag_factors: (T, T, T),
    /// Disturbance estimate: acceleration NED (m/s²) and angular acceleration body (rad/s²).
    dist: SVector<T, 6>,
    /// The two cascaded low-passes of the horizontal estimate the trend's
    /// rate comes from ([`Mpc::disturbance_rate`]).
    dist_lp: [[T; 2]; 2],
    /// Trend gain of prediction step k: `T·(1 − e^(−τ_k/T))`, s, τ_k the step's midpoint.
    trend: [T; N],
    last: Option<(Vec12<T>, T)>,
    last_qp: Option<MpcQp<T, NZ>>,
    /// The measured interval the next observer update spans, s
    /// ([`Controller::elapsed`]; `None`: the execution period).
    next_dt: Option<T>,
    /// The interval the last observer update spanned, s (the trend's rate
    /// filter differences over it).
    last_dt: T,
}

/// One channel of the prediction model ([`CHANNELS`]): the blocks of its
/// `K` states. The model couples no two channels (the design checks it), so
/// these are all of it that is not zero.
#[derive(Debug, Clone, Copy)]
struct Channel<T, const K: usize, const M: usize> {
    /// `a[i][j]`: the state matrix's entry from the channel's state `j` to its state `i`.
    a: [[T; K]; K],
    /// The input matrix's column of the channel's input.
    b: [T; K],
    /// The terminal weight's block.
    p: [[T; K]; K],
    /// `gx[m][j]`: the gradient of move `m` of the channel's input per unit
    /// initial value of its state `j` (the other channels' moves see none).
    gx: [[T; K]; M],
}

impl<T: RealField + Copy, const K: usize, const M: usize> Channel<T, K, M> {
    fn zero() -> Self {
        Self {
            a: [[T::zero(); K]; K],
            b: [T::zero(); K],
            p: [[T::zero(); K]; K],
            gx: [[T::zero(); K]; M],
        }
    }
}

/// The input channels (`U1` thrust, `U4` yaw torque) whose delivery the
/// observer models with the rotors' lag ([`MpcConfig::observer_rotor_lag`]).
const LAGGED_CHANNELS: [usize; 2] = [0, 3];

/// The prediction model's independent channels in the heading frame: each
/// input moves only its own states (state order `[x y z ẋ ẏ ż a₁ a₂ a₃ p q r
/// U_d1 U_d2 U_d3 U_d4]`, `a` the attitude coordinates, `U_d` what the
/// rotors deliver). Thrust: z, ż, U_d1; roll: y, ẏ, a₁, p, U_d2; pitch:
/// x, ẋ, a₂, q, U_d3; yaw: a₃, r, U_d4.
pub const CHANNELS: ([usize; 3], [usize; 5], [usize; 5], [usize; 3]) =
    ([2, 5, 12], [1, 4, 6, 9, 13], [0, 3, 7, 10, 14], [8, 11, 15]);

/// The move of prediction step `k` when each move but the last spans
/// `move_steps` steps ([`MpcConfig::move_steps`]; the last is held).
#[inline]
fn block_of<const M: usize>(k: usize, move_steps: usize) -> usize {
    (k / move_steps.max(1)).min(M - 1)
}

impl<T: RealField + Copy, const N: usize, const M: usize, const NZ: usize> Mpc<T, N, M, NZ> {
    /// Prediction steps (the horizon): also the number of reference preview points.
    pub const HORIZON: usize = N;

    /// Builds the MPC for the controller's vehicle `params`. Everything that
    /// does not depend on the measured state is computed here
    /// ([`Mpc::redesign`] on a blank controller).
    pub fn new(params: VehicleParams<T>, cfg: MpcConfig) -> Result<Self, ControlError> {
        let mut me = Self::blank(params, cfg);
        me.redesign(params, cfg)?;
        Ok(me)
    }

    /// An MPC with every matrix zero and the QP an identity: the storage
    /// that [`Mpc::redesign`] fills in place. Not a controller until then.
    // Design-time code: kept out of line so that its large frames are not
    // merged into the callers' (stack) and not copied into each (flash).
    #[inline(never)]
    pub fn blank(params: VehicleParams<T>, cfg: MpcConfig) -> Self {
        // The sizes are checked when the type is instantiated (compile errors).
        const {
            assert!(N > 0 && M > 0 && M <= N, "an MPC needs 1 ≤ M ≤ N");
            assert!(NZ == 4 * M, "NZ must be 4·M (four inputs per move)");
        };
        Self {
            cfg,
            bx: params.input_box(),
            u_hover: crate::model::hover_input(&params),
            params,
            zc: Channel::zero(),
            yc: Channel::zero(),
            xc: Channel::zero(),
            wc: Channel::zero(),
            wd: SMatrix::zeros(),
            ad_e: SMatrix::zeros(),
            bd_e: SMatrix::zeros(),
            wd_e: SMatrix::zeros(),
            q: Vec12::zeros(),
            gw: SMatrix::zeros(),
            gt: SMatrix::zeros(),
            r: Vector4::zeros(),
            s: Vector4::zeros(),
            qp: BoxQp::identity(),
            lb: SVector::zeros(),
            ub: SVector::zeros(),
            settings: qp_settings(&cfg),
            iteration_bound: 0,
            move_of: {
                // A move's index is kept in a byte.
                const { assert!(M <= u8::MAX as usize) };
                [0; N]
            },
            preview: [Setpoint::hold(Vector3::zeros(), T::zero()); N],
            preview_head: 0,
            preview_valid: false,
            preview_fresh: false,
            preview_age: T::zero(),
            z: SVector::zeros(),
            du_prev: Vector4::zeros(),
            du_delivered: Vector4::zeros(),
            lag_factors: (T::zero(), T::one(), T::one()),
            dist: SVector::zeros(),
            dist_lp: [[T::zero(); 2]; 2],
            trend: [T::zero(); N],
            last: None,
            last_qp: None,
            next_dt: None,
            last_dt: lit(cfg.exec_dt_s),
        }
    }

    /// The constant QP Hessian.
    pub fn hessian(&self) -> &SMatrix<T, NZ, NZ> {
        self.qp.hessian()
    }

    /// The a-priori QP iteration bound for the configured accuracy (computed
    /// once: the Hessian and the box never change); 1 when the QP is solved
    /// exactly ([`Mpc::qp_active_sets`]): one pass.
    pub fn iteration_bound(&self) -> u32 {
        self.iteration_bound
    }

    /// Active sets the exact QP solve tries on every step (`Σ 3^kᵢ` over
    /// the Hessian's independent blocks: 4 × 27 = 108 for the fast preset),
    /// or `None` when the QP is solved by the fast gradient method.
    pub fn qp_active_sets(&self) -> Option<u32> {
        match (self.settings.enumerate, self.qp.blocks()) {
            (true, Some(b)) => Some(b.active_sets()),
            _ => None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &MpcConfig {
        &self.cfg
    }

    /// The last QP solved (for inspection: `sil-host mpc-step`).
    pub fn last_qp(&self) -> Option<&MpcQp<T, NZ>> {
        self.last_qp.as_ref()
    }

    /// The last QP solved again by the MPC's own solver and settings, from
    /// the same start (for measuring the solve alone and for checks: the
    /// answer is the one the step used).
    pub fn resolve_last_qp(&self) -> Option<QpSolution<T, NZ>> {
        let qp = self.last_qp.as_ref()?;
        Some(self.qp.solve(&qp.g, &qp.lb, &qp.ub, &qp.warm, &self.settings))
    }

    /// Current disturbance estimate: acceleration NED (m/s²), angular
    /// acceleration body FRD (rad/s²).
    pub fn disturbance_estimate(&self) -> (Vector3<T>, Vector3<T>) {
        (
            self.dist.fixed_rows::<3>(0).into_owned(),
            self.dist.fixed_rows::<3>(3).into_owned(),
        )
    }

    /// Current rate of the horizontal disturbance estimate used by the damped
    /// trend, NED m/s³ (z is always 0; all zero without a trend): the
    /// second-order derivative filter `s/(τs + 1)²` of the estimate, the
    /// difference of its two cascaded low-passes over τ − dt (exact for a
    /// ramp in discrete time), each axis bounded so that `|ḋ|·T` stays within
    /// `disturbance_trend_max_mps2`.
    pub fn disturbance_rate(&self) -> Vector3<T> {
        let Some(tt) = self.cfg.disturbance_trend_s else {
            return Vector3::zeros();
        };
        // τ − dt of the last update (at least τ/2: a long step is not a
        // reason to divide by nearly nothing).
        let tau = lit::<T>(self.cfg.disturbance_rate_filter_s);
        let span = (tau - self.last_dt).max(tau * lit(0.5));
        let lim = lit::<T>(self.cfg.disturbance_trend_max_mps2 / tt);
        let rate = |i: usize| ((self.dist_lp[0][i] - self.dist_lp[1][i]) / span).max(-lim).min(lim);
        Vector3::new(rate(0), rate(1), T::zero())
    }

    /// Sets the reference for prediction step `k` (1-based: time
    /// `t + k·pred_dt`, `t` when the preview began). Once step `N` is set,
    /// the preview is complete, begun now, and the next update uses it;
    /// later updates use it only once told its age ([`Mpc::age_preview`]),
    /// and it can be moved on a step at a time ([`Mpc::roll_preview`]). A
    /// step below `N` leaves it incomplete until `N` is set. Without a
    /// complete preview the MPC extrapolates the current setpoint.
    pub fn set_preview(&mut self, k: usize, sp: &Setpoint<T>) -> Result<(), ControlError> {
        if k == 0 || k > N || !sp.is_valid() {
            return Err(ControlError::InvalidSetpoint);
        }
        let i = self.preview_head + k - 1;
        self.preview[if i >= N { i - N } else { i }] = *sp;
        self.preview_valid = k == N;
        if k == N {
            self.preview_fresh = true;
            self.preview_age = T::zero();
        }
        Ok(())
    }

    /// Moves the complete preview on by one step: step 1 goes, the others
    /// move down one, and `sp` is the new step `N` (the preview now begins
    /// `pred_dt` later; its age is the caller's to tell). Refused without a
    /// complete preview or for a set-point that is not finite.
    pub fn roll_preview(&mut self, sp: &Setpoint<T>) -> Result<(), ControlError> {
        if !self.preview_valid || !sp.is_valid() {
            return Err(ControlError::InvalidSetpoint);
        }
        self.preview[self.preview_head] = *sp;
        self.preview_head = if self.preview_head + 1 == N {
            0
        } else {
            self.preview_head + 1
        };
        Ok(())
    }

    /// The preview began `age_s` ago (at most the horizon): the
    /// next update uses it, each step extrapolated along its own
    /// derivatives by `age_s`. Refused (and the next update extrapolates
    /// the setpoint) without a complete preview or with an age that is
    /// not finite, negative or past the horizon.
    pub fn age_preview(&mut self, age_s: T) -> Result<(), ControlError> {
        let horizon = lit::<T>(self.cfg.pred_dt_s * N as f64);
        if !self.preview_valid || !age_s.is_finite() || age_s < T::zero() || age_s > horizon {
            self.preview_fresh = false;
            return Err(ControlError::InvalidSetpoint);
        }
        self.preview_age = age_s;
        self.preview_fresh = true;
        Ok(())
    }
}

impl<T: RealField + Copy, const N: usize, const M: usize, const NZ: usize> Controller<T> for Mpc<T, N, M, NZ> {
    fn update(&mut self, est: &StateEstimate<T>, sp: &Setpoint<T>) -> Result<ControlOutput<T>, ControlError> {
        validate(est, sp)?;
        self.observe(est);
        let yaw = quat_to_euler(&est.att)[2];
        let x0 = self.heading_state(est, yaw);
        let frame = HeadingFrame::new(yaw);
        // The prediction starts from the state and what the rotors deliver
        // now (zero when the prediction has no lag states).
        let mut x0p = VecX::<T>::zeros();
        x0p.fixed_rows_mut::<12>(0).copy_from(&x0);
        if self.predicts_lag() {
            x0p.fixed_rows_mut::<4>(12).copy_from(&self.du_delivered);
        }
        let d_acc = self.dist.fixed_rows::<3>(0).into_owned();
        let d_rate = self.disturbance_rate();
        // The state cost's gradient from the disturbance with its trend
        // (heading frame), through the responses computed at design: the
        // prediction needs no simulation here (the initial state's part
        // follows the references, which may move it).
        let mut g = mul(&self.gw, &self.dist_in(&frame));
        g += mul(&self.gt, &frame.to_frame(&d_rate));
        // The references over the horizon, as the errors of a zero state.
        let mut es = [VecX::<T>::zeros(); N];
        for (k, ek) in es.iter_mut().enumerate() {
            let spk = self.horizon_setpoint(sp, k + 1);
            // Disturbance of step k: the estimate plus its damped trend.
            let dk = d_acc + d_rate * self.trend[k];
            let (rk, du_ref) = self.reference_state(&spk, &dk, yaw, &frame);
            ek.fixed_rows_mut::<12>(0).copy_from(&-rk);
            if self.predicts_lag() {
                // What the rotors deliver at the reference: its input.
                ek.fixed_rows_mut::<4>(12).copy_from(&-du_ref);
            }
            // Input magnitude reference: the input of step k is move block_of(k).
            let b = self.move_of[k] as usize;
            for ch in 0..4 {
                g[4 * b + ch] -= self.r[ch] * du_ref[ch];
            }
        }
        // The reference brought within `max_position_error_m` of the
        // vehicle, by the shift its first step needs (no work without a
        // cap). The hover model's positions are pure integrators (no state
        // depends on them), so moving every reference position by −d is
        // moving the initial position by +d: three additions, not one per
        // step.
        if self.cfg.max_position_error_m.is_finite() {
            let e1 = -(es[0].fixed_rows::<3>(0) + x0.fixed_rows::<3>(0));
            if let Some(d) = self.reference_shift(&e1) {
                for i in 0..3 {
                    x0p[i] += d[i];
                }
            }
        }
        g += self.initial_response(&x0p);
        g += self.state_gradient(&es);
        for ch in 0..4 {
            g[ch] -= self.s[ch] * self.du_prev[ch];
        }
        // Warm start: the previous moves, shifted by one when a whole
        // prediction step has passed and a move is one step long.
        let mut warm = self.z;
        if self.cfg.exec_dt_s >= self.cfg.pred_dt_s && self.cfg.move_steps == 1 && M > 1 {
            for b in 0..M - 1 {
                for ch in 0..4 {
                    warm[4 * b + ch] = self.z[4 * (b + 1) + ch];
                }
            }
        }
        let sol = self.qp.solve(&g, &self.lb, &self.ub, &warm, &self.settings);
        self.z = sol.z;
        let du = Vector4::new(sol.z[0], sol.z[1], sol.z[2], sol.z[3]);
        let u = self.bx.clamp(&(self.u_hover + du));
        self.du_prev = u - self.u_hover;
        self.last = Some((x0, yaw));
        self.last_qp = Some(MpcQp {
            g,
            lb: self.lb,
            ub: self.ub,
            warm,
            solution: sol,
        });
        self.preview_fresh = false;
        Ok(ControlOutput {
            u,
            status: ControlStatus {
                saturated: false,
                excursion: 0.0,
                iterations: sol.iterations.min(u16::MAX as u32) as u16,
            },
        })
    }

    fn preview_request(&self) -> Option<(usize, f64)> {
        Some((N, self.cfg.pred_dt_s))
    }

    fn set_preview(&mut self, k: usize, sp: &Setpoint<T>) -> Result<(), ControlError> {
        Mpc::set_preview(self, k, sp)
    }

    fn age_preview(&mut self, age_s: T) -> Result<(), ControlError> {
        Mpc::age_preview(self, age_s)
    }

    fn roll_preview(&mut self, sp: &Setpoint<T>) -> Result<(), ControlError> {
        Mpc::roll_preview(self, sp)
    }

    fn period_s(&self) -> Option<f64> {
        Some(self.cfg.exec_dt_s)
    }

    fn iteration_bound(&self) -> u32 {
        Mpc::iteration_bound(self)
    }

    fn elapsed(&mut self, dt_s: T) {
        self.next_dt = super::plausible_step(dt_s, self.cfg.exec_dt_s).then_some(dt_s);
    }

    fn resume(&mut self) {
        self.last = None;
        // Over the gap (at least the link's failsafe timeout) the rotors
        // went on towards the input held: the lag model's delivered input
        // would otherwise be the one of the step before the gap.
        self.du_delivered = self.du_prev;
    }

    fn reset(&mut self) {
        self.z = SVector::zeros();
        self.du_prev = Vector4::zeros();
        self.du_delivered = Vector4::zeros();
        // At the nominal period, as the first step after a design or a
        // reset takes them: its exponential here, not in that step.
        self.lag_factors = self.lag_factors_over(lit(self.cfg.exec_dt_s));
        self.dist = SVector::zeros();
        self.dist_lp = [[T::zero(); 2]; 2];
        self.last = None;
        self.last_qp = None;
        self.next_dt = None;
        self.last_dt = lit(self.cfg.exec_dt_s);
        self.preview_valid = false;
        self.preview_fresh = false;
    }
}

/// The `thesis` preset's sizes: N = 20, M = 2.
pub type MpcThesis<T> = Mpc<T, 20, 2, 8>;
/// The `fast` preset's sizes: N = 20, M = 3.
pub type MpcFast<T> = Mpc<T, 20, 3, 12>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::VehicleParams;

    fn hover_at(z: f64) -> StateEstimate<f64> {
        StateEstimate {
            pos_ned_m: Vector3::new(0.0, 0.0, z),
            vel_ned_mps: Vector3::zeros(),
            att: Vector4::new(1.0, 0.0, 0.0, 0.0),
            rates_frd_radps: Vector3::zeros(),
        }
    }

    /// The channel-by-channel adjoint pass against the dense one over all
    /// 16 states of the design's own f64 model, with and without the
    /// rotors' lag states, with moves of one and three prediction steps.
    #[test]
    fn the_channel_adjoint_equals_the_dense_one() {
        let p = VehicleParams::<f64>::os4();
        for form in [AttitudeForm::Euler, AttitudeForm::Quaternion] {
            for (cfg, lag, move_steps) in [MpcConfig::fast(form), MpcConfig::thesis(form)]
                .into_iter()
                .flat_map(|c| [(c, false, 1), (c, true, 1), (c, true, 3)])
            {
                let mut cfg = cfg;
                cfg.rotor_lag_prediction = lag;
                cfg.move_steps = move_steps;
                let mpc = MpcFast::<f64>::new(p, cfg).unwrap();
                let m = design::prediction_model(&cfg, &p);
                // Arbitrary errors on every state at every step.
                let mut e = [VecX::<f64>::zeros(); 20];
                for (k, ek) in e.iter_mut().enumerate() {
                    for i in 0..PREDICTION_STATES {
                        ek[i] = libm::sin(1.3 * k as f64 + 0.7 * i as f64) * (1.0 + i as f64);
                    }
                }
                let mut q = VecX::<f64>::zeros();
                q.fixed_rows_mut::<12>(0).copy_from(&Vec12::from(cfg.q));
                let mut dense = SVector::<f64, 12>::zeros();
                let mut lambda = VecX::<f64>::zeros();
                for k in (0..20).rev() {
                    let w = if k == 19 {
                        m.p_term * e[k]
                    } else {
                        q.component_mul(&e[k])
                    };
                    lambda = w + m.ad.transpose() * lambda;
                    let gk = m.bd.transpose() * lambda;
                    for c in 0..4 {
                        dense[4 * block_of::<3>(k, cfg.move_steps) + c] += gk[c];
                    }
                }
                // The lag state is driven by no state of the vehicle, as
                // the channel pass assumes: exactly zero.
                for i in 0..12 {
                    for j in 12..PREDICTION_STATES {
                        assert_eq!(m.ad[(j, i)], 0.0, "lag state {j} driven by state {i}");
                    }
                }
                let a = mpc.state_gradient(&e);
                assert!(
                    (a - dense).amax() <= 1e-9 * dense.amax(),
                    "{form:?} lag {lag} moves of {move_steps}: {a} vs {dense}"
                );
            }
        }
    }

    /// Moves of no step, or so long that the last move would start past
    /// the horizon, are refused; the longest that leaves the last move one
    /// step is designed.
    #[test]
    fn move_blocking_past_the_horizon_is_refused() {
        let p = VehicleParams::<f64>::os4();
        let mut cfg = MpcConfig::fast(AttitudeForm::Euler);
        for (move_steps, ok) in [(0, false), (1, true), (9, true), (10, false), (usize::MAX, false)] {
            cfg.move_steps = move_steps;
            let r = MpcFast::<f64>::new(p, cfg);
            assert_eq!(r.is_ok(), ok, "moves of {move_steps} steps: {:?}", r.as_ref().err());
            if let Err(e) = r {
                assert_eq!(e, ControlError::InvalidParameter);
            }
        }
    }

    /// A reference farther than [`MpcConfig::max_position_error_m`] is
    /// flown as the one at that distance in its direction: from hover, a
    /// target 5 m away (x and y) under a 1.5 m cap asks for the very input
    /// an uncapped MPC asks for a target 1.5 m away; one nearer than the
    /// cap is not moved; a cap of no distance (0, negative, NaN) is refused.
    #[test]
    fn a_far_reference_is_flown_as_one_at_the_cap() {
        let p = VehicleParams::<f64>::os4();
        let est = hover_at(-1.0);
        let dir = Vector3::new(0.6, 0.8, 0.0);
        let at = |d: f64| Setpoint::hold(est.pos_ned_m + dir * d, 0.0);
        let mut capped_cfg = MpcConfig::fast(AttitudeForm::Euler);
        capped_cfg.max_position_error_m = 1.5;
        let first = |cfg: MpcConfig, sp: Setpoint<f64>| {
            let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
            mpc.update(&est, &sp).unwrap().u
        };
        let free = MpcConfig::fast(AttitudeForm::Euler);
        let (far, at_cap) = (first(capped_cfg, at(5.0)), first(free, at(1.5)));
        assert!((far - at_cap).amax() < 1e-9, "{far} vs {at_cap}");
        assert!((far - first(free, at(5.0))).amax() > 1e-3, "the cap changed nothing");
        let (near, near_free) = (first(capped_cfg, at(1.0)), first(free, at(1.0)));
        assert_eq!(near, near_free);
        for bad in [0.0, -1.0, f64::NAN] {
            let mut cfg = MpcConfig::fast(AttitudeForm::Euler);
            cfg.max_position_error_m = bad;
            assert_eq!(
                MpcFast::<f64>::new(p, cfg).err(),
                Some(ControlError::InvalidParameter),
                "{bad}"
            );
        }
    }

    /// The rotors in the prediction: a thrust step asked for from hover
    /// reaches the vehicle through the first-order lag, so the predicted
    /// climb is the analytic one of a lagged thrust, `ż(t) = −(Δ/m)·(t −
    /// τ(1 − e^(−t/τ)))` and `z(t) = −(Δ/m)·(t²/2 − τt + τ²(1 − e^(−t/τ)))`
    /// (NED, no drag), and what the rotors deliver is `Δ(1 − e^(−t/τ))`;
    /// without the lag states the prediction is the instant thrust's.
    #[test]
    fn the_prediction_delivers_thrust_through_the_rotors_lag() {
        let mut p = VehicleParams::<f64>::os4();
        p.kt_nspm = [0.0; 3];
        let (m, tau, du) = (p.mass_kg, p.rotor_tau_s, 1.5);
        for form in [AttitudeForm::Euler, AttitudeForm::Quaternion] {
            for lag in [true, false] {
                let mut cfg = MpcConfig::fast(form);
                cfg.rotor_lag_prediction = lag;
                let mpc = MpcFast::<f64>::new(p, cfg).unwrap();
                let b = mpc.input_column(0) * du;
                let mut x = VecX::<f64>::zeros();
                for k in 1..=20 {
                    x = mpc.predict(&x) + b;
                    let t = k as f64 * cfg.pred_dt_s;
                    let (vz, z, ud) = if lag {
                        let e = libm::exp(-t / tau);
                        let vz = -(du / m) * (t - tau * (1.0 - e));
                        let z = -(du / m) * (0.5 * t * t - tau * t + tau * tau * (1.0 - e));
                        (vz, z, du * (1.0 - e))
                    } else {
                        (-(du / m) * t, -(du / m) * 0.5 * t * t, 0.0)
                    };
                    let tol = 1e-9 * (1.0 + z.abs());
                    assert!((x[5] - vz).abs() < tol, "{form:?} lag {lag} t {t}: ż {} vs {vz}", x[5]);
                    assert!((x[2] - z).abs() < tol, "{form:?} lag {lag} t {t}: z {} vs {z}", x[2]);
                    assert!(
                        (x[12] - ud).abs() < 1e-9,
                        "{form:?} lag {lag} t {t}: U_d {} vs {ud}",
                        x[12]
                    );
                    // The other channels see none of it.
                    for i in [0, 1, 3, 4, 6, 7, 8, 9, 10, 11, 13, 14, 15] {
                        assert_eq!(x[i], 0.0, "{form:?} lag {lag}: state {i}");
                    }
                }
            }
        }
    }

    /// With the lag in its prediction, the MPC asks for a climb's thrust
    /// above a lag-blind MPC's, which expects it at once; and it starts each
    /// step from what the rotors deliver now: from the same state, rotors
    /// already delivering the thrust asked for are asked for less than
    /// rotors still spinning up.
    #[test]
    fn an_mpc_that_knows_its_rotors_asks_early() {
        let p = VehicleParams::<f64>::os4();
        let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -2.0), 0.0);
        let first = |lag: bool| {
            let mut cfg = MpcConfig::fast(AttitudeForm::Euler);
            cfg.rotor_lag_prediction = lag;
            let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
            mpc.update(&hover_at(-1.0), &sp).unwrap().u[0]
        };
        assert!(first(true) > first(false), "{} vs {}", first(true), first(false));
        // The same state, with the rotors told to be delivering the thrust
        // already asked for: less is asked again.
        let mut cfg = MpcConfig::fast(AttitudeForm::Euler);
        cfg.rotor_lag_prediction = true;
        let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
        let u1 = mpc.update(&hover_at(-1.0), &sp).unwrap().u[0];
        let mut spun = mpc.clone();
        spun.du_delivered[0] = u1 - mpc.u_hover[0];
        let (a, b) = (
            mpc.update(&hover_at(-1.0), &sp).unwrap().u[0],
            spun.update(&hover_at(-1.0), &sp).unwrap().u[0],
        );
        assert!(b < a, "rotors already delivering {u1}: {b} vs {a}");
    }

    /// The design checks that the continuous hover model couples no two
    /// channels before it designs them; a coupled one is refused.
    #[test]
    fn a_coupled_model_is_refused() {
        let p = VehicleParams::<f64>::os4();
        let w = design::ModelWork::<12>::hover(AttitudeForm::Euler, &p, None);
        assert!(design::channels_decouple(&w.a, &w.b_all));
        let mut coupled = design::ModelWork::<12>::hover(AttitudeForm::Euler, &p, None);
        coupled.a[(0, 1)] = 0.1; // x driven by y: no longer four channels
        assert!(!design::channels_decouple(&coupled.a, &coupled.b_all));
        let mut coupled = design::ModelWork::<12>::hover(AttitudeForm::Euler, &p, None);
        coupled.b_all[(5, 1)] = 0.1; // ż driven by the roll torque
        assert!(!design::channels_decouple(&coupled.a, &coupled.b_all));
    }

    /// At hover, with no disturbance, a step of any measured length is
    /// predicted as what it is: the estimate stays zero. Told nothing, a
    /// 3 ms step read as a 1 ms one would be. (Rotors without lag, as the
    /// observer is told: `rotors_that_lag_are_not_a_disturbance` has the lag.)
    #[test]
    fn a_measured_step_is_not_a_disturbance() {
        let p = VehicleParams::<f64>::os4();
        let mut cfg = MpcConfig::fast(AttitudeForm::Euler);
        cfg.exec_dt_s = 0.001;
        cfg.observer_rotor_lag = false;
        cfg.rotor_lag_prediction = false;
        // A climb: the thrust is not the hover thrust.
        let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -2.0), 0.0);
        // The vehicle from hover for `dt` under the MPC's first input, as the model has it.
        let fly = |tell: bool, dt: f64| {
            let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
            let mut est = hover_at(-1.0);
            let u = mpc.update(&est, &sp).unwrap().u;
            // The vertical acceleration the model predicts for the input sent.
            let a = p.gravity_mps2 - u[0] / p.mass_kg;
            est.vel_ned_mps[2] = a * dt;
            est.pos_ned_m[2] += 0.5 * a * dt * dt;
            if tell {
                mpc.elapsed(dt);
            }
            mpc.update(&est, &sp).unwrap();
            mpc.disturbance_estimate().0[2]
        };
        for dt in [0.001, 0.002, 0.003, 0.0017] {
            assert!(fly(true, dt).abs() < 1e-3, "dt {dt}: {}", fly(true, dt));
        }
        // Not told: the 3 ms step's extra velocity is taken for a force.
        assert!(fly(false, 0.003).abs() > 0.1, "{}", fly(false, 0.003));
        // An implausible interval is ignored (the nominal period).
        let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
        mpc.elapsed(f64::NAN);
        assert_eq!(mpc.next_dt, None);
        mpc.elapsed(1.0);
        assert_eq!(mpc.next_dt, None);
    }

    /// Rotors with the vehicle's first-order lag deliver, over a step, the
    /// lag's mean of the thrust sent: the observer that models the lag
    /// estimates no disturbance; one that compares with the thrust sent
    /// takes the thrust not yet delivered for a force (and asks for it
    /// again, the positive feedback that swung rotorpy's Crazyflie).
    #[test]
    fn rotors_that_lag_are_not_a_disturbance() {
        let p = VehicleParams::<f64>::os4();
        let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -2.0), 0.0);
        let fly = |lag_model: bool, dt: f64| {
            let mut cfg = MpcConfig::fast(AttitudeForm::Euler);
            cfg.observer_rotor_lag = lag_model;
            cfg.rotor_lag_prediction = lag_model;
            let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
            let mut est = hover_at(-1.0);
            let u = mpc.update(&est, &sp).unwrap().u;
            // From hover thrust towards u[0] with the rotors' time constant:
            // the mean over the step (the analytic first-order response).
            let u_hover = p.mass_kg * p.gravity_mps2;
            let r = dt / p.rotor_tau_s;
            let delivered = u[0] + (u_hover - u[0]) * (1.0 - (-r).exp()) / r;
            assert!((u[0] - u_hover).abs() > 1.0, "a climb asks for more thrust: {}", u[0]);
            let a = p.gravity_mps2 - delivered / p.mass_kg;
            est.vel_ned_mps[2] = a * dt;
            est.pos_ned_m[2] += 0.5 * a * dt * dt;
            mpc.elapsed(dt);
            mpc.update(&est, &sp).unwrap();
            mpc.disturbance_estimate().0[2]
        };
        for dt in [0.001, 0.002, 0.0017] {
            assert!(fly(true, dt).abs() < 1e-3, "dt {dt}: {}", fly(true, dt));
            assert!(fly(false, dt) > 0.05, "dt {dt}: {}", fly(false, dt));
        }
    }

    /// A design (and a re-design with another time constant) leaves the
    /// lag's factors of the nominal period in place, as the analytic
    /// first-order lag gives them: a first step at that period computes no
    /// exponential, and flies what one that computed it would.
    #[test]
    fn a_design_takes_the_lag_factors_of_its_period() {
        let mut p = VehicleParams::<f64>::os4();
        let cfg = MpcConfig::fast(AttitudeForm::Euler);
        assert!(cfg.observer_rotor_lag && p.rotor_tau_s > 0.0);
        let close = |got: (f64, f64, f64), tau: f64| {
            let r = cfg.exec_dt_s / tau;
            let (decay, mean) = (libm::exp(-r), (1.0 - libm::exp(-r)) / r);
            got.0 == cfg.exec_dt_s && (got.1 - decay).abs() < 1e-15 && (got.2 - mean).abs() < 1e-15
        };
        let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
        assert!(close(mpc.lag_factors, p.rotor_tau_s), "{:?}", mpc.lag_factors);
        // A step at the nominal period keeps them.
        let (est, sp) = (hover_at(-1.0), Setpoint::hold(Vector3::new(0.0, 0.0, -2.0), 0.0));
        let _ = mpc.update(&est, &sp);
        let _ = mpc.update(&est, &sp);
        assert!(close(mpc.lag_factors, p.rotor_tau_s), "{:?}", mpc.lag_factors);
        // A longer step takes its own, then a re-design for slower rotors.
        mpc.elapsed(0.002);
        let _ = mpc.update(&est, &sp);
        assert_eq!(mpc.lag_factors.0, 0.002);
        p.rotor_tau_s *= 2.0;
        mpc.redesign(p, cfg).unwrap();
        assert!(close(mpc.lag_factors, p.rotor_tau_s), "{:?}", mpc.lag_factors);
        // No lag modelled: the identity.
        let mut off = cfg;
        off.observer_rotor_lag = false;
        off.rotor_lag_prediction = false;
        mpc.redesign(p, off).unwrap();
        assert_eq!(mpc.lag_factors, (0.0, 1.0, 1.0));
    }

    /// A ramp north at 1 m/s, 1 m up: the reference at time `t` (s).
    fn ramp(t: f64) -> Setpoint<f64> {
        let mut sp = Setpoint::hold(Vector3::new(t, 0.0, -1.0), 0.0);
        sp.vel_ned_mps = Vector3::new(1.0, 0.0, 0.0);
        sp
    }

    /// A preview begun 10 ms ago and aged by that flies as one given now;
    /// one rolled on a step flies as one given a step later; an update not
    /// told the preview's age extrapolates the setpoint, as without one.
    #[test]
    fn a_preview_aged_or_rolled_flies_as_one_given_now() {
        let p = VehicleParams::<f64>::os4();
        let cfg = MpcConfig::fast(AttitudeForm::Quaternion);
        let h = cfg.pred_dt_s;
        let est = hover_at(-1.0);
        let fresh = MpcFast::<f64>::new(p, cfg).unwrap();
        let now = 0.5;
        let sp = ramp(now);
        let u = |mut m: MpcFast<f64>| m.update(&est, &sp).unwrap().u;
        let given_from = |base: f64| {
            let mut m = fresh.clone();
            for k in 1..=20 {
                m.set_preview(k, &ramp(base + k as f64 * h)).unwrap();
                // Incomplete until step N.
                assert_eq!(m.preview_valid, k == 20);
            }
            m
        };
        let given = given_from(now);
        let u_now = u(given.clone());
        // Begun 10 ms ago, then aged.
        let mut aged = given_from(now - 0.01);
        aged.age_preview(0.01).unwrap();
        assert!((u_now - u(aged)).abs().max() < 1e-9);
        // Begun a step and 10 ms ago, rolled on a step, aged 10 ms.
        let mut rolled = given_from(now - h - 0.01);
        rolled.roll_preview(&ramp(now - 0.01 + 20.0 * h)).unwrap();
        rolled.age_preview(0.01).unwrap();
        assert_eq!(rolled.preview_head, 1);
        assert!((u_now - u(rolled)).abs().max() < 1e-9);
        // The preview changes what the MPC asks: a held setpoint without one
        // asks for something else.
        let still = Setpoint::hold(sp.pos_ned_m, 0.0);
        let u_held = fresh.clone().update(&est, &still).unwrap().u;
        assert!((u_held - u_now).abs().max() > 1e-3, "the preview changed nothing");
        // Used by that update; the next, untold, extrapolates the setpoint.
        let mut used = given.clone();
        used.update(&est, &still).unwrap();
        let mut without = used.clone();
        without.preview_valid = false;
        let a = used.update(&est, &still).unwrap().u;
        let b = without.update(&est, &still).unwrap().u;
        assert!((a - b).abs().max() < 1e-12);
        // Ages that are not finite, negative or past the horizon, and a
        // roll or an age without a complete preview, are refused.
        for bad in [f64::NAN, -0.001, 20.0 * h + 0.001] {
            let mut m = given.clone();
            assert!(m.age_preview(bad).is_err());
            assert!(!m.preview_fresh);
        }
        let mut none = fresh.clone();
        assert!(none.age_preview(0.0).is_err());
        assert!(none.roll_preview(&sp).is_err());
        let mut nan = sp;
        nan.pos_ned_m[0] = f64::NAN;
        assert!(given.clone().roll_preview(&nan).is_err());
    }
}
