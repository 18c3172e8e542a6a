//! Closed-loop flights: the core's `f32` controller against the `f64` plant,
//! in-process, with the scenario's reference, recorded every 10 ms.

use crate::disturbance::DisturbanceSet;
pub use crate::disturbance::Uncertainty;
use crate::metrics::{flight_metrics, FlightMetrics, Trace};
use crate::plant::{ModelKind, Plant, PlantConfig};
use crate::record::{state_row, RECORD_DT_S};
use crate::scenario::{Reference, Scenario};
use firmware::control::{
    wrap_pi, AnyController, ControlError, Controller, LqrEuler, LqrQuat, MpcConfig, MpcFast, MpcForm, MpcThesis,
    PdEuler, PdEulerGains, PdQuat, PdQuatGains, ReferenceMode, Setpoint, StateEstimate,
};
use firmware::{hover_quat_state, VehicleParams};
use nalgebra::{Vector3, Vector4};
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Controller family, as chosen on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ControllerFamily {
    /// PD (thesis gains).
    Pd,
    /// LQR about hover (thesis weights), heading-scheduled.
    Lqr,
    /// Linear MPC with the core's QP solver (`--preset thesis|fast`).
    Mpc,
}

impl ControllerFamily {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            ControllerFamily::Pd => "pd",
            ControllerFamily::Lqr => "lqr",
            ControllerFamily::Mpc => "mpc",
        }
    }
}

/// MPC preset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum MpcPreset {
    /// Thesis: Ts = 0.25 s (4 Hz), N = 20, M = 2, thesis weights.
    Thesis,
    /// Project: 50 ms prediction over 1 s, re-solved at 200 Hz, M = 4.
    Fast,
}

impl MpcPreset {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            MpcPreset::Thesis => "thesis",
            MpcPreset::Fast => "fast",
        }
    }
}

/// Which gain set the PD controllers use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum GainSet {
    /// Thesis Tables 4.1–4.4 as printed.
    Thesis,
    /// The project's corrections where the printed gains do not fly (see `PdEulerGains::tuned`).
    Tuned,
}

/// Reference handling, as chosen on the command line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum RefMode {
    /// Thesis-faithful: reference position and velocity only.
    Thesis,
    /// Also feed forward the attitude and thrust implied by the reference acceleration.
    Feedforward,
}

impl From<RefMode> for ReferenceMode {
    fn from(m: RefMode) -> Self {
        match m {
            RefMode::Thesis => ReferenceMode::Thesis,
            RefMode::Feedforward => ReferenceMode::Feedforward,
        }
    }
}

/// Everything that defines one flight.
#[derive(Debug, Clone, Copy)]
pub struct FlightConfig {
    /// Controller family.
    pub controller: ControllerFamily,
    /// Form of the controller and of the plant.
    pub model: ModelKind,
    /// Reference handling.
    pub reference: RefMode,
    /// PD gain set (LQR always uses the thesis weights).
    pub gains: GainSet,
    /// MPC preset (MPC only).
    pub preset: MpcPreset,
    /// Replaces the preset's MPC configuration (sweeps, tuning); sizes stay the preset's.
    pub mpc_override: Option<MpcConfig>,
    /// What to fly.
    pub scenario: Scenario,
    /// Disturbances on the plant.
    pub disturbance: DisturbanceSet,
    /// Controller rate, Hz.
    pub control_hz: f64,
    /// Plant RK4 rate, Hz.
    pub integration_hz: f64,
    /// The vehicle: what the controllers are designed for and what the plant
    /// is (before `disturbance` and `uncertainty`). Default: the OS4 (SPEC §2).
    pub vehicle: VehicleParams<f64>,
    /// How the true vehicle differs from `vehicle` (robustness sweeps).
    pub uncertainty: Option<Uncertainty>,
    /// Errors on the state the controller sees (`None`: the true state).
    pub noise: Option<crate::noise::SensorNoise>,
}

impl FlightConfig {
    /// Defaults: feed-forward reference, 500 Hz control, 1 kHz plant.
    pub fn new(controller: ControllerFamily, model: ModelKind, scenario: Scenario) -> Self {
        Self {
            controller,
            model,
            reference: RefMode::Feedforward,
            gains: GainSet::Tuned,
            preset: MpcPreset::Fast,
            mpc_override: None,
            scenario,
            disturbance: DisturbanceSet::NONE,
            control_hz: 500.0,
            integration_hz: 1000.0,
            vehicle: VehicleParams::OS4,
            uncertainty: None,
            noise: None,
        }
    }
}

/// Controller time per step on the host, ns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StepTime {
    /// Mean over the flight.
    pub mean: f64,
    /// Worst step.
    pub max: f64,
}

/// A flown scenario.
#[derive(Debug, Clone)]
pub struct FlightResult {
    /// Recorded rows (state part, see [`crate::record::STATE_COLUMNS`]).
    pub rows: Vec<[f64; 21]>,
    /// Reference at each row `[x, y, z, ψ]`.
    pub reference: Vec<[f64; 4]>,
    /// What the metrics were computed from.
    pub trace: Trace,
    /// SPEC §10 metrics.
    pub metrics: FlightMetrics,
    /// Controller compute time on this host.
    pub step_time_ns: StepTime,
    /// Control steps in which the unconstrained law was clamped into the box.
    pub saturated_steps: usize,
    /// QP iterations per step (MPC): mean and max; zeros otherwise.
    pub qp_iterations: (f64, u32),
    /// The MPC's a-priori QP iteration bound (0 for other controllers).
    pub qp_iteration_bound: u32,
    /// Instructions per controller step under QEMU (mean, max); `None` elsewhere.
    pub instructions_per_step: Option<(f64, f64)>,
    /// Control steps flown.
    pub steps: usize,
    /// Steps the flight controller answered from its failsafe (remote targets).
    pub failsafe_steps: usize,
    /// The flight controller's frame and error counters at the end (remote targets).
    pub link_counters: Option<firmware::proto::Counters>,
    /// The firmware's own log (defmt, decoded), QEMU target only.
    pub firmware_log: Vec<String>,
    /// The flight was stopped because the state left any sane range.
    pub diverged: bool,
}

/// Builds the `f32` controller of a flight at sample time `ts` (s).
pub fn build_controller(
    family: ControllerFamily,
    model: ModelKind,
    gains: GainSet,
    preset: MpcPreset,
    mode: ReferenceMode,
    ts: f64,
) -> Result<AnyController<f32>, ControlError> {
    build_parts((family, model, gains, preset), None, mode, ts, &VehicleParams::OS4)
}

/// The controller of a flight as `cfg` describes it (its vehicle, and its
/// MPC configuration override if any) at PD/LQR sample time `ts` (s).
pub fn build_for(cfg: &FlightConfig, ts: f64) -> Result<AnyController<f32>, ControlError> {
    build_parts(
        (cfg.controller, cfg.model, cfg.gains, cfg.preset),
        cfg.mpc_override,
        cfg.reference.into(),
        ts,
        &cfg.vehicle,
    )
}

fn build_parts(
    (family, model, gains, preset): (ControllerFamily, ModelKind, GainSet, MpcPreset),
    mpc: Option<MpcConfig>,
    mode: ReferenceMode,
    ts: f64,
    vehicle: &VehicleParams<f64>,
) -> Result<AnyController<f32>, ControlError> {
    let p: VehicleParams<f32> = vehicle.cast();
    Ok(match (family, model) {
        (ControllerFamily::Mpc, _) => {
            let form = MpcForm::from(model);
            match preset {
                MpcPreset::Thesis => {
                    AnyController::MpcThesis(MpcThesis::new(p, mpc.unwrap_or(MpcConfig::thesis(form)))?)
                }
                MpcPreset::Fast => AnyController::MpcFast(MpcFast::new(p, mpc.unwrap_or(MpcConfig::fast(form)))?),
            }
        }
        (ControllerFamily::Pd, ModelKind::Euler) => {
            let g = match gains {
                GainSet::Thesis => PdEulerGains::thesis(),
                GainSet::Tuned => PdEulerGains::tuned(),
            };
            AnyController::PdEuler(PdEuler::new(p, g, mode))
        }
        (ControllerFamily::Pd, ModelKind::Quaternion) => {
            let g = match gains {
                GainSet::Thesis => PdQuatGains::thesis(),
                GainSet::Tuned => PdQuatGains::tuned(),
            };
            AnyController::PdQuat(PdQuat::new(p, g, mode))
        }
        (ControllerFamily::Lqr, ModelKind::Euler) => AnyController::LqrEuler(LqrEuler::thesis(p, ts, mode)?),
        (ControllerFamily::Lqr, ModelKind::Quaternion) => AnyController::LqrQuat(LqrQuat::thesis(p, ts, mode)?),
    })
}

fn setpoint(r: &Reference) -> Setpoint<f32> {
    Setpoint {
        pos_ned_m: r.pos.cast(),
        vel_ned_mps: r.vel.cast(),
        acc_ned_mps2: r.acc.cast(),
        jerk_ned_mps3: r.jerk.cast(),
        yaw_rad: r.yaw as f32,
        yaw_rate_radps: r.yaw_rate as f32,
    }
}

/// Where the controller runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    /// Called directly in this process.
    InProcess,
    /// The flight-controller core in this process, reached only through the
    /// framed wire protocol over a loopback byte link.
    Framed,
    /// A flight controller behind the protocol on a TCP socket (`sil-host serve`).
    Tcp(String),
    /// The thumbv7em firmware image in QEMU's netduinoplus2, over the emulated USART.
    Qemu,
}

impl std::str::FromStr for Target {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "in-process" => Ok(Target::InProcess),
            "framed" => Ok(Target::Framed),
            "qemu" => Ok(Target::Qemu),
            _ => match s.strip_prefix("tcp:") {
                Some(addr) if !addr.is_empty() => Ok(Target::Tcp(addr.to_string())),
                _ => Err(format!(
                    "unknown target '{s}': use in-process, framed, qemu or tcp:HOST:PORT"
                )),
            },
        }
    }
}

/// The wire id of a flight's controller (PD always with the tuned gains).
pub fn controller_id(cfg: &FlightConfig) -> firmware::proto::ControllerId {
    use firmware::proto::ControllerId as C;
    match (cfg.controller, cfg.model, cfg.preset) {
        (ControllerFamily::Pd, ModelKind::Euler, _) => C::PdEuler,
        (ControllerFamily::Pd, ModelKind::Quaternion, _) => C::PdQuat,
        (ControllerFamily::Lqr, ModelKind::Euler, _) => C::LqrEuler,
        (ControllerFamily::Lqr, ModelKind::Quaternion, _) => C::LqrQuat,
        (ControllerFamily::Mpc, ModelKind::Euler, MpcPreset::Fast) => C::MpcFastEuler,
        (ControllerFamily::Mpc, ModelKind::Quaternion, MpcPreset::Fast) => C::MpcFastQuat,
        (ControllerFamily::Mpc, ModelKind::Euler, MpcPreset::Thesis) => C::MpcThesisEuler,
        (ControllerFamily::Mpc, ModelKind::Quaternion, MpcPreset::Thesis) => C::MpcThesisQuat,
    }
}

/// Flies one scenario in-process.
pub fn fly(cfg: &FlightConfig) -> anyhow::Result<FlightResult> {
    fly_until(cfg, None, |_, _| {}).map(|(r, _)| r)
}

/// Flies one scenario with the controller at `target`.
pub fn fly_target(cfg: &FlightConfig, target: &Target) -> anyhow::Result<FlightResult> {
    fly_target_with_progress(cfg, target, false)
}

/// [`fly_target`], with a progress bar on standard error for remote targets
/// when `progress`.
pub fn fly_target_with_progress(cfg: &FlightConfig, target: &Target, progress: bool) -> anyhow::Result<FlightResult> {
    let mut qemu = None;
    let remote = match target {
        Target::InProcess => return fly(cfg),
        Target::Framed => crate::link::FcClient::local()?,
        Target::Tcp(addr) => crate::link::FcClient::tcp(addr)?,
        Target::Qemu => {
            let q = qemu.insert(crate::link::Qemu::start(&crate::link::firmware_elf()?)?);
            q.client()?
        }
    };
    if cfg.vehicle != VehicleParams::OS4 {
        anyhow::bail!(
            "over the link the flight controller flies its built-in vehicle (the OS4); --vehicle works in-process only"
        );
    }
    if cfg.gains != GainSet::Tuned
        || cfg.mpc_override.is_some()
        || (cfg.controller != ControllerFamily::Mpc && (cfg.control_hz - 500.0).abs() > 1e-9)
    {
        anyhow::bail!("over the link the flight controller runs its built-in configuration: tuned PD gains, LQR at 500 Hz, MPC presets");
    }
    // The local controller only paces the flight (period, preview size); the
    // remote one flies it.
    let pace = build_controller(
        cfg.controller,
        cfg.model,
        cfg.gains,
        cfg.preset,
        cfg.reference.into(),
        1.0 / cfg.control_hz,
    )
    .map_err(|e| anyhow::anyhow!("controller design failed: {e:?}"))?;
    // Remote flights take real time (QEMU: milliseconds a step): show progress.
    let bar = crate::study::progress_bar(
        (cfg.scenario.duration_s * 10.0).round() as usize,
        "× 0.1 s flown",
        progress,
    );
    bar.set_message(format!("{target:?}"));
    let tick = |t: f64, _: &AnyController<f32>| bar.set_position((t * 10.0) as u64);
    let mut res = fly_inner(cfg, pace, None, Some(remote), tick).map(|(r, _)| r)?;
    bar.finish_and_clear();
    if let Some(q) = qemu {
        // The telemetry's cycles are SysTick counts; under icount they count instructions.
        let k = 1.0 / crate::link::SYSTICK_PER_INSTRUCTION;
        res.instructions_per_step = Some((res.step_time_ns.mean * k, res.step_time_ns.max * k));
        res.firmware_log = q.finish()?;
    }
    Ok(res)
}

/// Flies `cfg` up to `stop_at` seconds (the whole scenario when `None`),
/// calling `inspect(t, controller)` after every control step; returns the
/// result and the controller as it was at the end.
pub fn fly_until(
    cfg: &FlightConfig,
    stop_at: Option<f64>,
    inspect: impl FnMut(f64, &AnyController<f32>),
) -> anyhow::Result<(FlightResult, AnyController<f32>)> {
    let ctrl = build_for(cfg, 1.0 / cfg.control_hz).map_err(|e| anyhow::anyhow!("controller design failed: {e:?}"))?;
    fly_inner(cfg, ctrl, stop_at, None, inspect)
}

/// Flies `cfg` with a controller built by the caller (e.g. an MPC with a
/// horizon no preset has); `cfg`'s controller fields then only label it.
pub fn fly_with<C: Controller<f32>>(cfg: &FlightConfig, ctrl: C) -> anyhow::Result<FlightResult> {
    fly_inner(cfg, ctrl, None, None, |_, _| {}).map(|(r, _)| r)
}

fn fly_inner<C: Controller<f32>>(
    cfg: &FlightConfig,
    mut ctrl: C,
    stop_at: Option<f64>,
    mut remote: Option<crate::link::FcClient>,
    mut inspect: impl FnMut(f64, &C),
) -> anyhow::Result<(FlightResult, C)> {
    cfg.scenario.validate().map_err(anyhow::Error::msg)?;
    if !(cfg.integration_hz.is_finite() && cfg.integration_hz >= 1.0) {
        anyhow::bail!("integration rate must be at least 1 Hz");
    }
    // The MPC presets fix their own execution period; PD/LQR run at control_hz.
    let probe_ts = 1.0 / cfg.control_hz;
    let ts = ctrl.period_s().unwrap_or(probe_ts);
    if !(ts.is_finite() && ts > 0.0) {
        anyhow::bail!("control rate must be positive");
    }
    // Everything advances in plant ticks; control and recording fall on ticks.
    let tick = 1.0 / cfg.integration_hz;
    let per = |period: f64, what: &str| -> anyhow::Result<usize> {
        let n = (period / tick).round();
        if n < 1.0 || (n * tick - period).abs() > 1e-9 {
            anyhow::bail!("the {what} period {period} s is not a whole number of plant steps of {tick} s");
        }
        Ok(n as usize)
    };
    let ctrl_every = per(ts, "control")?;
    let rec_every = per(RECORD_DT_S, "recording")?;
    let mut pc = PlantConfig {
        params: cfg.vehicle,
        ..PlantConfig::nominal(cfg.model)
    }
    .with_disturbance(cfg.disturbance);
    if let Some(u) = cfg.uncertainty {
        pc.params = u.apply(&pc.params);
        pc.rotor_lag |= u.rotor_tau_s.is_some();
    }
    pc.integration_hz = cfg.integration_hz;
    let sc = &cfg.scenario;
    let x0 = hover_quat_state(&Vector3::from(sc.start_ned_m), sc.start_yaw_rad);
    let mut plant = Plant::new(pc, &x0);
    let nominal = cfg.vehicle;
    let end = stop_at.unwrap_or(sc.duration_s).min(sc.duration_s);
    let ticks = (end / tick).round() as usize;
    let preview = ctrl.preview_request();
    if let Some(r) = remote.as_mut() {
        r.open(controller_id(cfg), cfg.reference == RefMode::Feedforward)?;
    }
    let mut seq = 0u32;
    let mut sensors = cfg.noise.map(|n| n.source());

    let mut res = FlightResult {
        rows: Vec::new(),
        reference: Vec::new(),
        trace: Trace::default(),
        metrics: flight_metrics(&Trace::default(), &nominal),
        step_time_ns: StepTime { mean: 0.0, max: 0.0 },
        saturated_steps: 0,
        qp_iterations: (0.0, 0),
        qp_iteration_bound: ctrl.iteration_bound(),
        instructions_per_step: None,
        steps: 0,
        failsafe_steps: 0,
        link_counters: None,
        firmware_log: Vec::new(),
        diverged: false,
    };
    let mut total_ns = 0.0;
    let mut total_it = 0u64;
    let mut u = Vector4::<f64>::zeros();
    for i in 0..=ticks {
        let t = i as f64 * tick;
        let r = sc.reference(t);
        if i % ctrl_every == 0 {
            let xq = plant.quat_state();
            if !xq.iter().all(|v| v.is_finite()) || xq.fixed_rows::<3>(0).amax() > 1e4 {
                res.diverged = true;
                break;
            }
            // What the controller sees: the true state, or its noisy measurement.
            let xq = match sensors.as_mut() {
                Some(s) => s.measure(&xq),
                None => xq,
            };
            let est = StateEstimate::from_quat_state(&xq.cast::<f32>());
            let sp = setpoint(&r);
            let previews: Vec<Setpoint<f32>> = match preview {
                Some((n, dt)) => (1..=n).map(|k| setpoint(&sc.reference(t + k as f64 * dt))).collect(),
                None => Vec::new(),
            };
            let dt_ns;
            if let Some(link) = remote.as_mut() {
                seq += 1;
                let state: [f32; 13] = std::array::from_fn(|i| xq[i] as f32);
                // A preview the setpoint's own extrapolation reproduces is not
                // sent: the controller extrapolates to the same values, and a
                // fixed target then costs 2 frames a step instead of 22.
                let dt = preview.map_or(0.0, |(_, dt)| dt);
                let redundant = previews.iter().enumerate().all(|(k, p)| {
                    let e = sp.extrapolate(((k + 1) as f64 * dt) as f32);
                    setpoints_equal(&e, p)
                });
                let sent: &[Setpoint<f32>] = if redundant { &[] } else { &previews };
                let step = link.step(seq, (t * 1e6) as u64, &state, &sp, sent)?;
                // The flight controller reports its own time per step (ns on the host).
                dt_ns = step.cycles as f64;
                total_it += u64::from(step.qp_iterations);
                res.qp_iterations.1 = res.qp_iterations.1.max(u32::from(step.qp_iterations));
                u = Vector4::from(step.u).cast::<f64>();
                res.failsafe_steps += usize::from(step.failsafe);
                res.link_counters = Some(step.counters);
            } else {
                for (k, p) in previews.iter().enumerate() {
                    // The scenario defines the reference; a rejected point only
                    // means the controller extrapolates instead.
                    let _ = ctrl.set_preview(k + 1, p);
                }
                let t0 = Instant::now();
                let out = ctrl.update(&est, &sp);
                dt_ns = t0.elapsed().as_nanos() as f64;
                // An estimate built from a finite state is always valid: on the
                // impossible error the loop holds the last command (its fallback).
                if let Ok(o) = out {
                    res.saturated_steps += usize::from(o.status.saturated);
                    total_it += u64::from(o.status.iterations);
                    res.qp_iterations.1 = res.qp_iterations.1.max(u32::from(o.status.iterations));
                    u = o.u.cast::<f64>();
                }
            }
            total_ns += dt_ns;
            res.step_time_ns.max = res.step_time_ns.max.max(dt_ns);
            res.steps += 1;
            inspect(t, &ctrl);
        }
        if i % rec_every == 0 {
            let mut row = state_row(&plant);
            row[17..21].copy_from_slice(plant.inputs_realised_for(&u).as_slice());
            let yaw = row[13];
            let yaw_unwrapped = r.yaw + wrap_pi(yaw - r.yaw);
            let rref = [r.pos[0], r.pos[1], r.pos[2], r.yaw];
            res.trace.t.push(t);
            res.trace.actual.push([row[1], row[2], row[3], yaw_unwrapped]);
            res.trace.reference.push(rref);
            res.trace.u_cmd.push([u[0], u[1], u[2], u[3]]);
            res.rows.push(row);
            res.reference.push(rref);
        }
        if i < ticks {
            plant.step(&u, tick);
        }
    }
    if res.steps > 0 {
        res.step_time_ns.mean = total_ns / res.steps as f64;
        res.qp_iterations.0 = total_it as f64 / res.steps as f64;
    }
    res.metrics = flight_metrics(&res.trace, &nominal);
    Ok((res, ctrl))
}

/// Equal to f32 rounding (relative 1e-6, absolute 1e-6).
fn setpoints_equal(a: &Setpoint<f32>, b: &Setpoint<f32>) -> bool {
    let close = |x: f32, y: f32| (x - y).abs() <= 1e-6 * (1.0 + x.abs().max(y.abs()));
    let vclose =
        |x: &nalgebra::Vector3<f32>, y: &nalgebra::Vector3<f32>| x.iter().zip(y.iter()).all(|(p, q)| close(*p, *q));
    vclose(&a.pos_ned_m, &b.pos_ned_m)
        && vclose(&a.vel_ned_mps, &b.vel_ned_mps)
        && vclose(&a.acc_ned_mps2, &b.acc_ned_mps2)
        && vclose(&a.jerk_ned_mps3, &b.jerk_ned_mps3)
        && close(a.yaw_rad, b.yaw_rad)
        && close(a.yaw_rate_radps, b.yaw_rate_radps)
}
