//! Closed-loop flights: the core's `f32` controller against the `f64` plant,
//! with the scenario's reference, recorded every 10 ms. Where the controller
//! runs is an [`Endpoint`] (`crate::endpoint`): in this process
//! ([`InProcess`]) or behind the wire protocol ([`crate::link::Remote`]:
//! framed in-process, TCP, QEMU); the flight loop here is the same for all.

use crate::disturbance::DisturbanceSet;
pub use crate::disturbance::Uncertainty;
pub use crate::endpoint::{Endpoint, InProcess, StepReport};
use crate::metrics::{FlightMetrics, MetricsAccumulator, Trace};
use crate::plant::{Plant, PlantConfig};
use crate::record::{state_row, RowSink, RECORD_DT_S};
use crate::scenario::{FlatOutput, Scenario};
use crate::sensors::IMU_PERIOD_S;
use fc_core::control::{wrap_pi, AnyController, Controller, ControllerSpec, Family, MpcConfig, Setpoint, Tuning};
use fc_core::{hover_quat_state, AttitudeForm, QuatState, VehicleParams};
use nalgebra::{Vector3, Vector4};
use serde::{Deserialize, Serialize};

/// Everything that defines one flight.
#[derive(Debug, Clone, Copy)]
pub struct FlightConfig {
    /// The controller; its attitude form is also the plant's.
    pub spec: ControllerSpec,
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
    /// is (before `disturbance` and `uncertainty`). Default: the OS4 (docs/book/src/model.md §2).
    pub vehicle: VehicleParams<f64>,
    /// How the true vehicle differs from `vehicle` (robustness sweeps).
    pub uncertainty: Option<Uncertainty>,
    /// Errors on the state the controller sees (`None`: the true state).
    pub noise: Option<crate::noise::SensorNoise>,
    /// Fly from simulated sensors through the on-board estimator (`None`:
    /// the controller is handed the true state, or `noise`'s version of it).
    pub sensors: Option<crate::sensors::SensorConfig>,
    /// A sensor outage `(start s, duration s)`: no sensor frame reaches the
    /// controller in that window (the plant keeps the last input), as when
    /// the link or the sensors drop out. `None`: none.
    pub sensor_gap: Option<(f64, f64)>,
    /// The simulator's step grid for true-state flights (`None`: the
    /// controller's own period, one step per control period): the flight
    /// controller is stepped at every grid point and runs its controller on
    /// its schedule, as behind a simulator that steps at 2 ms, 3 ms or an
    /// uneven grid.
    pub step_grid: Option<StepGrid>,
    /// Over a link: parameter reads (`ParamRead`, cycling through the
    /// table) sent with every step, right after its sample, as a ground
    /// station polling the parameters would; their answers are read and
    /// dropped. 0: none.
    pub param_flood: u16,
}

/// A simulator's step grid: steps `period ± jitter` apart (uniform, from a
/// seeded generator), each on a plant tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepGrid {
    /// Mean time between steps, s.
    pub period_s: f64,
    /// Largest deviation of one interval from the period, s (0: even).
    pub jitter_s: f64,
    /// Seed of the jitter.
    pub seed: u64,
}

impl StepGrid {
    /// An even grid of `period_s`.
    pub fn even(period_s: f64) -> Self {
        Self {
            period_s,
            jitter_s: 0.0,
            seed: 1,
        }
    }

    /// Refuses a grid that is not a grid: a period outside (0, 1] s, or a
    /// jitter that is negative, non-finite or not below the period.
    pub fn validate(&self) -> anyhow::Result<()> {
        let (p, j) = (self.period_s, self.jitter_s);
        if !(p.is_finite() && p > 0.0 && p <= 1.0) {
            anyhow::bail!("--step-grid period {p:?} s is out of range: must be in (0, 1] s");
        }
        if !(j.is_finite() && j >= 0.0 && j < p) {
            anyhow::bail!("--step-grid jitter {j:?} s is out of range: must be in [0, the period {p} s)");
        }
        Ok(())
    }

    /// The intervals of the grid, in plant ticks of `tick` s (each at least one).
    fn intervals(&self, tick: f64) -> impl FnMut() -> usize {
        let (period, jitter) = (self.period_s, self.jitter_s);
        let mut rng = crate::noise::SplitMix(self.seed);
        move || {
            let dt = period + rng.uniform(-jitter, jitter);
            ((dt / tick).round() as usize).max(1)
        }
    }
}

/// Most parameter reads sent with one step (`--param-flood`): 16 reads a
/// 1 kHz step are 16 000 a second, several hundred times what a ground
/// station asks.
pub const MAX_PARAM_FLOOD: u16 = 16;

/// Fastest plant integration rate accepted, Hz.
pub const MAX_INTEGRATION_HZ: f64 = 100_000.0;

impl FlightConfig {
    /// Refuses what cannot be flown honestly, before anything is designed
    /// or flown, naming the value and its flag: the scenario's ranges
    /// ([`Scenario::validate`]), a reference the vehicle cannot follow
    /// ([`Scenario::check_feasible`]), the vehicle's parameters
    /// ([`VehicleParams::check`]), the control rate (finite, > 0, at
    /// most the plant's) and the plant rate (1 Hz … 100 kHz).
    pub fn validate(&self) -> anyhow::Result<()> {
        self.vehicle
            .check()
            .map_err(|e| anyhow::anyhow!("{e} (the vehicle: --vehicle FILE, or the built-in OS4)"))?;
        self.scenario.validate().map_err(anyhow::Error::msg)?;
        self.scenario
            .check_feasible(&self.vehicle)
            .map_err(anyhow::Error::msg)?;
        let ih = self.integration_hz;
        if !(ih.is_finite() && (1.0..=MAX_INTEGRATION_HZ).contains(&ih)) {
            anyhow::bail!("--integration-hz {ih:?} is out of range: must be in [1, {MAX_INTEGRATION_HZ}] Hz");
        }
        let ch = self.control_hz;
        if !(ch.is_finite() && ch > 0.0 && ch <= ih) {
            anyhow::bail!("--control-hz {ch:?} is out of range: must be > 0 and at most --integration-hz ({ih} Hz)");
        }
        if self.param_flood > MAX_PARAM_FLOOD {
            anyhow::bail!(
                "--param-flood {} is out of range: at most {MAX_PARAM_FLOOD} reads a step",
                self.param_flood
            );
        }
        if let Some(g) = &self.step_grid {
            g.validate()?;
            if self.sensors.is_some() {
                anyhow::bail!("--step-grid steps a true-state flight (add --estimator truth); a sensor flight steps at its IMU's samples");
            }
        }
        Ok(())
    }

    /// Defaults: feed-forward reference, 500 Hz control, 1 kHz plant.
    pub fn new(controller: Family, model: AttitudeForm, scenario: Scenario) -> Self {
        Self {
            spec: ControllerSpec::new(controller, model),
            mpc_override: None,
            scenario,
            disturbance: DisturbanceSet::NONE,
            control_hz: 500.0,
            integration_hz: 1000.0,
            vehicle: VehicleParams::OS4,
            uncertainty: None,
            noise: None,
            sensors: None,
            sensor_gap: None,
            step_grid: None,
            param_flood: 0,
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

/// What a flight keeps of its record rows (one per [`RECORD_DT_S`]).
pub enum Recording<'a> {
    /// Rows, references and the trace in the [`FlightResult`] (for plots and
    /// tests); memory grows with the flight's length.
    Keep,
    /// Each row (with its reference) to the sink as it is produced, nothing
    /// kept: the result's `rows`, `reference` and `trace` stay empty, the
    /// metrics are computed online. Memory is constant in the flight's length.
    Stream(&'a mut dyn RowSink),
}

/// A flown scenario.
#[derive(Debug, Clone)]
pub struct FlightResult {
    /// Recorded rows (state part, see [`crate::record::STATE_COLUMNS`]);
    /// empty when the flight was [`Recording::Stream`]ed.
    pub rows: Vec<[f64; 21]>,
    /// Reference at each row `[x, y, z, ψ]`; empty when streamed.
    pub reference: Vec<[f64; 4]>,
    /// The samples the metrics are computed from; empty when streamed.
    pub trace: Trace,
    /// docs/book/src/model.md §10 metrics.
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
    /// Sensor flights: the cost of the IMU steps between the controller's
    /// runs (the estimator alone), in `step_time_ns`'s unit; `None` otherwise.
    pub estimator_step_time: Option<StepTime>,
    /// The same in instructions under QEMU (mean, max).
    pub estimator_instructions_per_step: Option<(f64, f64)>,
    /// The rate the controller was flown at, Hz: `control_hz` for PD and
    /// LQR, the preset's own rate for the MPC.
    pub control_hz: f64,
    /// Control steps flown.
    pub steps: usize,
    /// Steps the flight controller answered from its failsafe (remote targets).
    pub failsafe_steps: usize,
    /// The flight controller's frame and error counters at the end (remote targets).
    pub link_counters: Option<fc_proto::Counters>,
    /// The firmware's own log (defmt, decoded), QEMU target only.
    pub firmware_log: Vec<String>,
    /// The flight was stopped because the state left any sane range.
    pub diverged: bool,
    /// The on-board estimator's errors and counts (sensor flights).
    pub estimation: Option<crate::estimation::EstimationResult>,
}

/// The controller of a flight as `cfg` describes it (its vehicle, and its
/// MPC configuration override if any), PD and LQR at `cfg.control_hz`.
pub fn build_for(cfg: &FlightConfig) -> anyhow::Result<AnyController<f32>> {
    cfg.validate()?;
    cfg.spec
        .build_with(
            cfg.vehicle.cast(),
            1.0 / cfg.control_hz,
            cfg.mpc_override,
            &Tuning::project(),
        )
        .map_err(|e| anyhow::anyhow!("designing {} failed: {e}", cfg.spec))
}

fn setpoint(r: &FlatOutput) -> Setpoint<f32> {
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

/// Flies one scenario in-process.
pub fn fly(cfg: &FlightConfig) -> anyhow::Result<FlightResult> {
    fly_until(cfg, None, |_, _| {}).map(|(r, _)| r)
}

/// Flies one scenario with the controller at `target`.
pub fn fly_target(cfg: &FlightConfig, target: &Target) -> anyhow::Result<FlightResult> {
    fly_target_with_progress(cfg, target, None, Recording::Keep)
}

/// [`fly_target`], calling `progress(t)` with the simulated time after every
/// control step (remote flights take real time: the CLI draws a bar with
/// it), the rows recorded as `rec` says.
pub fn fly_target_with_progress(
    cfg: &FlightConfig,
    target: &Target,
    progress: Option<&dyn Fn(f64)>,
    rec: Recording<'_>,
) -> anyhow::Result<FlightResult> {
    use crate::link::{firmware_elf, FcClient, Qemu, Remote, SYSTICK_PER_INSTRUCTION};
    cfg.validate()?;
    let tick = |t: f64| {
        if let Some(p) = progress {
            p(t)
        }
    };
    if *target == Target::InProcess {
        if cfg.param_flood > 0 {
            anyhow::bail!("--param-flood needs a flight controller behind a link (--target framed, tcp:… or qemu)");
        }
        let ep = InProcess::new(build_for(cfg)?);
        return fly_endpoint(cfg, ep, None, |t, _| tick(t), rec).map(|(r, _)| r);
    }
    if cfg.mpc_override.is_some()
        || (cfg.spec.family != fc_core::control::Family::Mpc && (cfg.control_hz - 500.0).abs() > 1e-9)
    {
        anyhow::bail!("over the link the flight controller runs its built-in configuration: PD and LQR at 500 Hz, the MPC presets");
    }
    // Refused before anything starts: a controller with no wire id.
    cfg.spec.to_wire().map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut qemu = None;
    let mut client = match target {
        Target::InProcess => anyhow::bail!("an in-process flight has no link"),
        Target::Framed => FcClient::local()?,
        Target::Tcp(addr) => FcClient::tcp(addr)?,
        Target::Qemu => qemu.insert(Qemu::start(&firmware_elf()?)?).client()?,
    };
    client.flood_param_reads(cfg.param_flood);
    // The vehicle's parameters are written over the link (ParamSet) before the selection.
    let flown = Remote::open(client, cfg.spec, &cfg.vehicle)
        .and_then(|remote| fly_endpoint(cfg, remote, None, |t, _| tick(t), rec));
    let (mut res, _) = match (flown, qemu.take()) {
        (Ok(r), q) => {
            qemu = q;
            r
        }
        // What the image logged is what says why it stopped answering.
        (Err(e), Some(q)) => {
            let log = q
                .finish()
                .unwrap_or_else(|d| vec![format!("(its log could not be decoded: {d})")]);
            return Err(e.context(format!("the image in QEMU logged:\n  {}", log.join("\n  "))));
        }
        (Err(e), None) => return Err(e),
    };
    if let Some(q) = qemu {
        // The telemetry's cycles are SysTick counts; under icount they count instructions.
        let k = 1.0 / SYSTICK_PER_INSTRUCTION;
        res.instructions_per_step = Some((res.step_time_ns.mean * k, res.step_time_ns.max * k));
        res.estimator_instructions_per_step = res.estimator_step_time.map(|e| (e.mean * k, e.max * k));
        res.firmware_log = q.finish()?;
    }
    Ok(res)
}

/// Flies `cfg` in-process up to `stop_at` seconds (the whole scenario when
/// `None`), calling `inspect(t, controller)` after every control step;
/// returns the result and the controller as it was at the end.
pub fn fly_until(
    cfg: &FlightConfig,
    stop_at: Option<f64>,
    mut inspect: impl FnMut(f64, &AnyController<f32>),
) -> anyhow::Result<(FlightResult, AnyController<f32>)> {
    let ep = InProcess::new(build_for(cfg)?);
    let (res, ep) = fly_endpoint(
        cfg,
        ep,
        stop_at,
        |t, ep: &InProcess<_>| inspect(t, &ep.ctrl),
        Recording::Keep,
    )?;
    Ok((res, ep.ctrl))
}

/// Flies `cfg` with a controller built by the caller (e.g. an MPC with a
/// horizon no preset has); `cfg`'s controller fields then only label it.
pub fn fly_with<C: Controller<f32>>(cfg: &FlightConfig, ctrl: C) -> anyhow::Result<FlightResult> {
    fly_endpoint(cfg, InProcess::new(ctrl), None, |_, _| {}, Recording::Keep).map(|(r, _)| r)
}

/// The flight loop: the plant at `cfg.integration_hz`, one `endpoint` step
/// per control period, a record row every 10 ms kept or streamed as `rec`
/// says; `inspect(t, endpoint)` after every control step. Returns the
/// result and the endpoint.
pub fn fly_endpoint<E: Endpoint>(
    cfg: &FlightConfig,
    mut ep: E,
    stop_at: Option<f64>,
    mut inspect: impl FnMut(f64, &E),
    mut rec: Recording<'_>,
) -> anyhow::Result<(FlightResult, E)> {
    cfg.validate()?;
    // The MPC presets fix their own execution period; PD/LQR run at control_hz.
    let ts = ep.period_s().unwrap_or(1.0 / cfg.control_hz);
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
        ..PlantConfig::nominal(cfg.spec.form)
    }
    .with_disturbance(cfg.disturbance);
    let mut latency_ticks = 0usize;
    if let Some(u) = cfg.uncertainty {
        pc.params = u.apply(&pc.params);
        pc.rotor_lag |= u.rotor_tau_s.is_some();
        pc.wind_ned_mps = Vector3::from(u.wind_ned_mps);
        if !(u.latency_s.is_finite() && (0.0..=1.0).contains(&u.latency_s)) {
            anyhow::bail!(
                "sensor latency {:?} s is out of range: must be in [0, 1] s",
                u.latency_s
            );
        }
        latency_ticks = (u.latency_s * cfg.integration_hz).round() as usize;
    }
    // The true states of the last `latency_ticks` plant steps: the
    // controller sees the oldest (the initial state until there is history).
    let mut history: std::collections::VecDeque<QuatState<f64>> =
        std::collections::VecDeque::with_capacity(latency_ticks + 1);
    pc.integration_hz = cfg.integration_hz;
    let sc = &cfg.scenario;
    let x0 = hover_quat_state(&Vector3::from(sc.start_ned_m), sc.start_yaw_rad);
    let mut plant = Plant::new(pc, &x0);
    let nominal = cfg.vehicle;
    let end = stop_at.unwrap_or(sc.duration_s).min(sc.duration_s);
    let ticks = (end / tick).round() as usize;
    let preview = ep.preview();
    let mut sensors = cfg.noise.map(|n| n.source());
    let mut imu_fix = match cfg.sensors {
        Some(sc) => {
            if cfg.noise.is_some() {
                anyhow::bail!(
                    "--noise perturbs the true state; a sensor flight (--estimator ekf) has its own sensor noise"
                );
            }
            if latency_ticks > 0 {
                anyhow::bail!(
                    "a state latency models a delayed true state; a sensor flight's latencies are its sensors'"
                );
            }
            Some(crate::sensors::Sensors::new(sc, IMU_PERIOD_S)?)
        }
        None => None,
    };
    // Sensor flights step at every IMU sample and run the controller on its
    // schedule (whole IMU periods: its grid then falls on IMU steps).
    let imu_every = per(IMU_PERIOD_S, "IMU")?;
    if imu_fix.is_some() && ctrl_every % imu_every != 0 {
        anyhow::bail!(
            "a sensor flight runs the controller on IMU steps ({} ms): the control period {ts} s is not a whole number of them",
            IMU_PERIOD_S * 1e3
        );
    }
    let ctrl_period_us = fc_loop::schedule::period_us(ts);
    // The simulator's own grid (true-state flights): the next tick it steps at.
    let mut grid = cfg.step_grid.map(|g| g.intervals(tick));
    let mut next_grid_tick = 0usize;
    let mut schedule = fc_loop::schedule::Schedule::new();
    let mut est_acc = crate::estimation::EstimationAccumulator::default();
    let mut est_trace = Vec::new();
    // The estimate of the last IMU step, for a streaming sink's next row.
    let mut last_nav: Option<crate::endpoint::NavReport> = None;

    let mut res = FlightResult {
        rows: Vec::new(),
        reference: Vec::new(),
        trace: Trace::default(),
        metrics: MetricsAccumulator::new(&nominal).metrics(),
        step_time_ns: StepTime { mean: 0.0, max: 0.0 },
        saturated_steps: 0,
        qp_iterations: (0.0, 0),
        qp_iteration_bound: ep.iteration_bound(),
        instructions_per_step: None,
        estimator_step_time: None,
        estimator_instructions_per_step: None,
        control_hz: 1.0 / ts,
        steps: 0,
        failsafe_steps: 0,
        link_counters: None,
        firmware_log: Vec::new(),
        diverged: false,
        estimation: None,
    };
    let mut metrics = MetricsAccumulator::new(&nominal).tracking_from(sc.tracking_from_s());
    let mut total_cost = 0.0;
    let mut total_it = 0u64;
    let mut failing_since: Option<f64> = None;
    // Sum, max and count of the estimator-only steps' costs.
    let mut est_cost = (0.0, 0.0f64, 0usize);
    // The plant starts in hover: until the first output, hold its inputs.
    // (In f32, as the flight controller computes it: an aligning estimator
    // holds the same command in-process and on the image.)
    let mut u = fc_core::hover_input(&cfg.vehicle.cast::<f32>()).cast::<f64>();
    for i in 0..=ticks {
        let t = i as f64 * tick;
        let r = sc.reference(t);
        if latency_ticks > 0 {
            if history.len() > latency_ticks {
                history.pop_front();
            }
            history.push_back(plant.quat_state());
        }
        let in_gap = cfg.sensor_gap.is_some_and(|(start, len)| t >= start && t < start + len);
        // A step of the endpoint: every control period on the true state;
        // every IMU sample in a sensor flight, the controller on its schedule.
        // A true-state flight on the simulator's grid steps the controller
        // when it is due there (a grid finer than its period skips steps).
        let on_grid = match grid.as_mut() {
            Some(next) if i == next_grid_tick => {
                next_grid_tick += next();
                !in_gap && schedule.due((t * 1e6).round() as u64, ctrl_period_us)
            }
            Some(_) => false,
            None => i % ctrl_every == 0,
        };
        let stepped = !in_gap
            && match imu_fix {
                Some(_) => i % imu_every == 0,
                None => on_grid,
            };
        if stepped {
            let xq = plant.quat_state();
            if !xq.iter().all(|v| v.is_finite()) || xq.fixed_rows::<3>(0).amax() > 1e4 {
                res.diverged = true;
                break;
            }
            let control = imu_fix.is_none() || schedule.due((t * 1e6).round() as u64, ctrl_period_us);
            let sp = setpoint(&r);
            let previews: Vec<Setpoint<f32>> = match preview {
                Some((n, dt)) if control => (1..=n).map(|k| setpoint(&sc.reference(t + k as f64 * dt))).collect(),
                _ => Vec::new(),
            };
            let step = match imu_fix.as_mut() {
                Some(s) => {
                    let readings = s.read(t, &plant);
                    let step = ep.step_sensed(t, &readings, &sp, &previews, control)?;
                    if let Some(nav) = &step.nav {
                        est_acc.push(t, &plant.quat_state(), &s.true_biases(), nav);
                        last_nav = Some(*nav);
                    }
                    step
                }
                None => {
                    let xq = if latency_ticks > 0 {
                        history.front().copied().unwrap_or(xq)
                    } else {
                        xq
                    };
                    // What the controller sees: the true state, or its noisy measurement.
                    let xq = match sensors.as_mut() {
                        Some(s) => s.measure(&xq),
                        None => xq,
                    };
                    ep.step(t, &xq, &sp, &previews)?
                }
            };
            if control {
                if let Some(v) = step.u {
                    u = Vector4::from(v).cast::<f64>();
                    failing_since = None;
                } else {
                    // The loop holds the last command; a controller that fails
                    // for a whole second is a flight that cannot be reported.
                    let since = *failing_since.get_or_insert(t);
                    if step.nav.is_some_and(|n| n.mode == fc_loop::nav::NavMode::Aligning) && t - since >= 1.0 {
                        anyhow::bail!(
                            "the estimator did not align in 1 s (it needs IMU samples at rest, a position fix and a heading)"
                        );
                    }
                    if t - since >= 1.0 {
                        anyhow::bail!(
                            "the controller produced no output at any step from t = {since:.3} s to {t:.3} s \
                             (it refuses its state or setpoint); the flight is abandoned"
                        );
                    }
                }
                res.saturated_steps += usize::from(step.saturated);
                res.failsafe_steps += usize::from(step.failsafe);
                total_it += u64::from(step.iterations);
                res.qp_iterations.1 = res.qp_iterations.1.max(u32::from(step.iterations));
                total_cost += step.cost;
                res.step_time_ns.max = res.step_time_ns.max.max(step.cost);
                res.steps += 1;
                inspect(t, &ep);
            }
            if step.counters.is_some() {
                res.link_counters = step.counters;
            }
            if !control {
                est_cost.0 += step.cost;
                est_cost.1 = est_cost.1.max(step.cost);
                est_cost.2 += 1;
            }
        }
        if i % rec_every == 0 {
            let mut row = state_row(&plant);
            row[17..21].copy_from_slice(plant.inputs_realised_for(&u).as_slice());
            let yaw = row[13];
            let yaw_unwrapped = r.yaw + wrap_pi(yaw - r.yaw);
            let rref = [r.pos[0], r.pos[1], r.pos[2], r.yaw];
            let actual = [row[1], row[2], row[3], yaw_unwrapped];
            let u_cmd = [u[0], u[1], u[2], u[3]];
            metrics.push(t, &actual, &rref, &u_cmd);
            match &mut rec {
                Recording::Keep => {
                    if let Some(s) = est_acc.last().filter(|s| (s.t - t).abs() < 1e-9) {
                        est_trace.push(s);
                    }
                    res.trace.t.push(t);
                    res.trace.actual.push(actual);
                    res.trace.reference.push(rref);
                    res.trace.u_cmd.push(u_cmd);
                    res.rows.push(row);
                    res.reference.push(rref);
                }
                Recording::Stream(sink) => {
                    sink.push(&row, Some(&rref))?;
                    if let Some(nav) = last_nav.take() {
                        sink.estimate(t, &nav)?;
                    }
                }
            }
        }
        if i < ticks {
            plant.step(&u, tick);
        }
    }
    if res.steps > 0 {
        res.step_time_ns.mean = total_cost / res.steps as f64;
        res.qp_iterations.0 = total_it as f64 / res.steps as f64;
    }
    res.metrics = metrics.metrics();
    if imu_fix.is_some() {
        res.estimation = Some(est_acc.result(est_trace));
        if est_cost.2 > 0 {
            res.estimator_step_time = Some(StepTime {
                mean: est_cost.0 / est_cost.2 as f64,
                max: est_cost.1,
            });
        }
    }
    Ok((res, ep))
}
