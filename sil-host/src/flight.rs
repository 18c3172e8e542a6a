//! Closed-loop flights: the core's `f32` controller against the `f64` plant,
//! in-process, with the scenario's reference, recorded every 10 ms.

use crate::disturbance::DisturbanceSet;
use crate::metrics::{flight_metrics, FlightMetrics, Trace};
use crate::plant::{ModelKind, Plant, PlantConfig};
use crate::record::{state_row, RECORD_DT_S};
use crate::scenario::{Reference, Scenario};
use firmware::control::{
    wrap_pi, AnyController, ControlError, Controller, LqrEuler, LqrQuat, PdEuler, PdEulerGains, PdQuat, PdQuatGains,
    ReferenceMode, Setpoint, StateEstimate,
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
}

impl ControllerFamily {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            ControllerFamily::Pd => "pd",
            ControllerFamily::Lqr => "lqr",
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
    /// What to fly.
    pub scenario: Scenario,
    /// Disturbances on the plant.
    pub disturbance: DisturbanceSet,
    /// Controller rate, Hz.
    pub control_hz: f64,
    /// Plant RK4 rate, Hz.
    pub integration_hz: f64,
}

impl FlightConfig {
    /// Defaults: feed-forward reference, 500 Hz control, 1 kHz plant.
    pub fn new(controller: ControllerFamily, model: ModelKind, scenario: Scenario) -> Self {
        Self {
            controller,
            model,
            reference: RefMode::Feedforward,
            gains: GainSet::Tuned,
            scenario,
            disturbance: DisturbanceSet::NONE,
            control_hz: 500.0,
            integration_hz: 1000.0,
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
    /// Control steps flown.
    pub steps: usize,
    /// The flight was stopped because the state left any sane range.
    pub diverged: bool,
}

/// Builds the `f32` controller of a flight at sample time `ts` (s).
pub fn build_controller(
    family: ControllerFamily,
    model: ModelKind,
    gains: GainSet,
    mode: ReferenceMode,
    ts: f64,
) -> Result<AnyController<f32>, ControlError> {
    let p = VehicleParams::<f32>::os4();
    Ok(match (family, model) {
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

/// Flies one scenario in-process.
pub fn fly(cfg: &FlightConfig) -> anyhow::Result<FlightResult> {
    cfg.scenario.validate().map_err(anyhow::Error::msg)?;
    if !(cfg.control_hz.is_finite() && cfg.control_hz >= 1.0) {
        anyhow::bail!("control rate must be at least 1 Hz");
    }
    let ts = 1.0 / cfg.control_hz;
    let mut ctrl = build_controller(cfg.controller, cfg.model, cfg.gains, cfg.reference.into(), ts)
        .map_err(|e| anyhow::anyhow!("controller design failed: {e:?}"))?;
    let mut pc = PlantConfig::nominal(cfg.model).with_disturbance(cfg.disturbance);
    pc.integration_hz = cfg.integration_hz;
    let sc = &cfg.scenario;
    let x0 = hover_quat_state(&Vector3::from(sc.start_ned_m), sc.start_yaw_rad);
    let mut plant = Plant::new(pc, &x0);
    let nominal = VehicleParams::OS4;

    let steps = (sc.duration_s * cfg.control_hz).round() as usize;
    let mut res = FlightResult {
        rows: Vec::new(),
        reference: Vec::new(),
        trace: Trace::default(),
        metrics: flight_metrics(&Trace::default(), &nominal),
        step_time_ns: StepTime { mean: 0.0, max: 0.0 },
        saturated_steps: 0,
        steps: 0,
        diverged: false,
    };
    let mut next_record = 0.0;
    let mut total_ns = 0.0;
    let mut u_hold = Vector4::<f64>::zeros();
    for k in 0..=steps {
        let t = k as f64 * ts;
        let r = sc.reference(t);
        let xq = plant.quat_state();
        if !xq.iter().all(|v| v.is_finite()) || xq.fixed_rows::<3>(0).amax() > 1e4 {
            res.diverged = true;
            break;
        }
        let est = StateEstimate::from_quat_state(&xq.cast::<f32>());
        let sp = setpoint(&r);
        let t0 = Instant::now();
        let out = ctrl.update(&est, &sp);
        let dt_ns = t0.elapsed().as_nanos() as f64;
        let u = match out {
            Ok(o) => {
                res.saturated_steps += usize::from(o.status.saturated);
                o.u.cast::<f64>()
            }
            // The estimate is built from a finite state, so this does not happen
            // in the SIL; hold the last command as the loop's fallback.
            Err(_) => u_hold,
        };
        u_hold = u;
        total_ns += dt_ns;
        res.step_time_ns.max = res.step_time_ns.max.max(dt_ns);
        res.steps += 1;
        if t + 1e-9 >= next_record {
            let mut row = state_row(&plant);
            row[17..21].copy_from_slice(plant.inputs_realised_for(&u).as_slice());
            let yaw = row[13];
            // Yaw relative to the reference, unwrapped.
            let yaw_unwrapped = r.yaw + wrap_pi(yaw - r.yaw);
            let rref = [r.pos[0], r.pos[1], r.pos[2], r.yaw];
            res.trace.t.push(t);
            res.trace.actual.push([row[1], row[2], row[3], yaw_unwrapped]);
            res.trace.reference.push(rref);
            res.trace.u_cmd.push([u[0], u[1], u[2], u[3]]);
            res.rows.push(row);
            res.reference.push(rref);
            next_record += RECORD_DT_S;
        }
        if k < steps {
            plant.step(&u, ts);
        }
    }
    res.step_time_ns.mean = if res.steps > 0 {
        total_ns / res.steps as f64
    } else {
        0.0
    };
    res.metrics = flight_metrics(&res.trace, &nominal);
    Ok(res)
}
