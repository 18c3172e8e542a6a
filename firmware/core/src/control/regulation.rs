//! The hover regulation problem on which the MPC is compared with a peer
//! solver (TinyMPC): the host benchmark (`sil-host/benches/mpc.rs`) and the
//! chip's `peer` harness (`fc-stm32f405`, in QEMU) both fly this one
//! definition, so "the same problem" is the same code.
//!
//! The OS4's Euler hover model, exact ZOH at 50 ms; the benchmark's own Q
//! ([`Weights::Benchmark`]) and the fast preset's R, with no input-rate cost
//! (TinyMPC has none); the OS4's input box around hover; a 20-step horizon;
//! [`STEPS`] closed-loop steps on the linear model from [`start`], no
//! disturbance. Our MPC predicts with the plant's own model (no rotor lag:
//! this linear plant has none).

use super::{AttitudeForm, ControlError, Controller, MpcConfig, MpcFast, ReferenceMode, Setpoint, StateEstimate};
use crate::model::{euler_hover_model, euler_to_quat, hover_input, zoh, VehicleParams};
use nalgebra::{SMatrix, SVector, Vector3, Vector4};

/// Closed-loop steps of one episode.
pub const STEPS: usize = 60;
/// Prediction steps of the horizon (TinyMPC: as many states, one input fewer).
pub const HORIZON: usize = 20;

/// The state: `[x y z, vx vy vz, φ θ ψ, p q r]` (NED m, m/s, rad, body FRD rad/s).
pub type State = SVector<f32, 12>;
/// The input relative to hover, `U − U_hover` (N, N·m).
pub type Input = Vector4<f32>;

/// The prediction model: the ZOH of the Euler hover model at the preset's
/// 50 ms prediction step, `x⁺ = A x + B (U − U_hover)`.
pub fn model() -> Result<(SMatrix<f32, 12, 12>, SMatrix<f32, 12, 4>), ControlError> {
    let p = VehicleParams::<f64>::os4();
    let lm = euler_hover_model(&p, 0.0);
    let (a, b) = zoh(&lm.a, &lm.b, config().pred_dt_s)?;
    Ok((a.cast(), b.cast()))
}

/// The start state: (1.5, −1, 0.8) m from the target, at rest, level.
pub fn start() -> State {
    let mut x = State::zeros();
    x[0] = 1.5;
    x[1] = -1.0;
    x[2] = 0.8;
    x
}

/// The roll/pitch-rate weights (Q's p and q entries) of the problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Weights {
    /// 600 on roll and pitch rate: the benchmark's own, fixed when it was
    /// introduced (the fast preset's of then), so that the peer table
    /// stays comparable while the flight preset is tuned.
    Benchmark,
    /// The fast flight preset's rate weights ([`MpcConfig::fast`], 1.8):
    /// light, because the flight MPC predicts its rotors' lag.
    Flight,
}

/// Roll/pitch-rate weight of [`Weights::Benchmark`].
pub const BENCHMARK_RATE_WEIGHT: f64 = 600.0;

/// The fast preset as a pure regulator of the linear plant, with the
/// benchmark's rate weights ([`config_with`] of [`Weights::Benchmark`]).
pub fn config() -> MpcConfig {
    config_with(Weights::Benchmark)
}

/// The fast preset as a pure regulator of the linear plant: one
/// closed-loop step per prediction step, the plant's model (no rotor lag),
/// no disturbance estimate, no input-rate cost, every QP solve certified
/// (no iteration cap); roll/pitch-rate weights as `w` says.
pub fn config_with(w: Weights) -> MpcConfig {
    let mut c = MpcConfig::fast(AttitudeForm::Euler);
    if w == Weights::Benchmark {
        c.q[9] = BENCHMARK_RATE_WEIGHT;
        c.q[10] = BENCHMARK_RATE_WEIGHT;
    }
    c.rotor_lag_prediction = false;
    c.exec_dt_s = c.pred_dt_s;
    c.observer_tau_s = None;
    c.disturbance_trend_s = None;
    c.reference = ReferenceMode::Thesis;
    c.s = [1e-6; 4];
    c.qp_max_iterations = u32::MAX;
    c
}

/// The input box around hover, `(lo, hi)` of `U − U_hover`.
pub fn input_box() -> (Input, Input) {
    let p = VehicleParams::<f32>::os4();
    let (bx, uh) = (p.input_box(), hover_input(&p));
    (bx.lo - uh, bx.hi - uh)
}

/// Stage cost `xᵀQx + uᵀRu` with the weights of `c` ([`config_with`]).
pub fn stage_cost(c: &MpcConfig, x: &State, u: &Input) -> f64 {
    let sq = |v: f32| (v as f64) * (v as f64);
    (0..12).map(|i| c.q[i] * sq(x[i])).sum::<f64>() + (0..4).map(|i| c.r[i] * sq(u[i])).sum::<f64>()
}

/// One episode: [`STEPS`] closed-loop steps from [`start`] on the linear
/// model, `solve(x)` giving each step's input (clamped into the box here);
/// returns the closed-loop cost with the weights of `c`, or `None` when
/// `solve` fails.
pub fn episode(
    c: &MpcConfig,
    a: &SMatrix<f32, 12, 12>,
    b: &SMatrix<f32, 12, 4>,
    mut solve: impl FnMut(&State) -> Option<Input>,
) -> Option<f64> {
    let (lo, hi) = input_box();
    let mut x = start();
    let mut cost = 0.0;
    for _ in 0..STEPS {
        let u = solve(&x)?.zip_zip_map(&lo, &hi, |v, l, h| v.max(l).min(h));
        cost += stage_cost(c, &x, &u);
        x = a * x + b * u;
    }
    Some(cost)
}

/// The state `x` as the estimate a controller reads (Euler angles → quaternion).
pub fn estimate(x: &State) -> StateEstimate<f32> {
    StateEstimate {
        pos_ned_m: Vector3::new(x[0], x[1], x[2]),
        vel_ned_mps: Vector3::new(x[3], x[4], x[5]),
        att: euler_to_quat(x[6], x[7], x[8]),
        rates_frd_radps: Vector3::new(x[9], x[10], x[11]),
    }
}

/// The target: hover at the origin, heading north.
pub fn target() -> Setpoint<f32> {
    Setpoint::hold(Vector3::zeros(), 0.0)
}

/// Our MPC's answer for state `x`: `U − U_hover` and its QP iterations.
pub fn ours(mpc: &mut MpcFast<f32>, x: &State) -> Option<(Input, u16)> {
    let out = mpc.update(&estimate(x), &target()).ok()?;
    Some((out.u - hover_input(&VehicleParams::<f32>::os4()), out.status.iterations))
}
