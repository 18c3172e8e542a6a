//! `sil-host`: fly the flight-control core against the nonlinear plant.
//!
//! Subcommands: `open-loop` (constant inputs from hover). Closed-loop
//! flights (`fly`), controller design (`design`), MPC step inspection
//! (`mpc-step`), the framed-link server (`serve`) and the study (`report`,
//! `sweep`) build on the same plant, scenarios and metrics.

use anyhow::{bail, Context, Result};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand};
use fc_core::control::{Family, Preset, ReferenceMode, SPECS};
use fc_core::AttitudeForm;
use sil_host::disturbance::DisturbanceSet;
use sil_host::flight::Recording;
use sil_host::flight::{FlightConfig, Target};
use sil_host::flight_log::{FlyULog, Tee};
use sil_host::openloop::OpenLoop;
use sil_host::plant::PlantConfig;
use sil_host::record::{CsvSink, Discard, STATE_COLUMNS};
use sil_host::scenario::{Scenario, ScenarioKind};
use sil_host::sensors::{FixProfile, SensorConfig};
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "sil-host",
    version,
    about = "Software-in-the-loop host for the quadrotor flight-control core",
    long_about = "Flies the no_std flight-control core against a nonlinear f64 plant built from the \
                  same equations (docs/book/src/model.md). Frames: earth NED (z down, altitude = -z), body FRD; \
                  angles in rad unless an option says degrees."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Fly constant inputs from hover (thesis §3.5.3) and write the trajectory as CSV.
    OpenLoop(OpenLoopArgs),
    /// Fly a scenario in closed loop with a controller of the core; print metrics, write CSV/JSON.
    Fly(FlyArgs),
    /// Print a controller design (the linear model, the weights and the gain) as JSON.
    Design(DesignArgs),
    /// Serve the flight-controller core behind the framed protocol on a TCP socket: a virtual flight
    /// controller. Clients are served one after another; garbage is dropped and counted, and a client
    /// that hangs up or goes idle ends only its own session.
    Serve(ServeArgs),
    /// Fly a scenario with the MPC up to time T and print the QP of the step taken there as JSON:
    /// {"H","g","lb","ub","solution","iterations","iteration_bound","solve_bound","iterations_allowed",
    /// "certified_accuracy","gap","residual","objective","status"}.
    MpcStep(MpcStepArgs),
    /// Fly the whole study (every controller x model x scenario x disturbance) in parallel and write
    /// DIR/index.md and a self-contained DIR/index.html: the thesis' tables with ours beside its
    /// numbers and why they differ, figures (DIR/figures, SVG and PNG), the horizon sweep and the
    /// instructions per step in QEMU (when qemu-system-arm is installed).
    Report(ReportArgs),
    /// Monte Carlo robustness: every controller against many true vehicles (mass, inertia, drag,
    /// rotor lag drawn from a seeded generator); writes DIR/sweep.md (success rate, RMSE
    /// percentiles), DIR/sweep.json (every flight) and the RMSE-distribution figure.
    Sweep(SweepArgs),
    /// Fly the core against a simulator that speaks PX4's HIL interface (it listens on TCP 4560:
    /// rotorpy's PX4Multirotor, jMAVSim, Gazebo's bridge): HIL_SENSOR in, HIL_ACTUATOR_CONTROLS
    /// out, in lockstep; HIL_STATE_QUATERNION's position and heading as a mocap-like fix. Motors
    /// off until armed (refused until the estimator has aligned at rest); the mission is sent in
    /// as a ground station's commands, or a real ground station (--gcs) flies it. Prints a JSON
    /// summary.
    Px4Hil(Px4HilArgs),
    /// Be a Crazyflie for cflib and cfclient: CRTP over UDP (cflib's `udp://` driver, one datagram
    /// per packet), the flight controller flying the SIL's plant in real time on its own sensors
    /// (estimator on), from rest on the ground. Connect with `udp://127.0.0.1:19850`. Prints a JSON
    /// summary when --duration ends.
    Crtp(CrtpArgs),
    /// Draw the report's position figures (position against time, the path seen from above) from
    /// a ULog: this project's (`fly --ulog`, `px4-hil --ulog`) or PX4's own. Flown position: the
    /// ground truth when the log has it, else vehicle_local_position; the set-point dashed.
    Plot(PlotArgs),
    /// Print this command-line reference as Markdown: the book's chapter
    /// docs/book/src/cli.md is this output, checked by a test.
    #[command(hide = true)]
    MarkdownHelp,
}

#[derive(Args, Debug)]
struct PlotArgs {
    /// The ULog to draw.
    #[arg(long, value_name = "FILE")]
    ulog: PathBuf,
    /// Output directory for DIR/STEM_position.svg|png and DIR/STEM_path_top.svg|png (created if
    /// missing); STEM is the log's file name.
    #[arg(long, default_value = "figures", value_name = "DIR")]
    out: PathBuf,
}

#[derive(Args, Debug, Clone)]
struct CrtpArgs {
    /// The UDP address to listen on (cflib scans ports 19850–19859 of 127.0.0.1).
    #[arg(long, default_value = "127.0.0.1:19850", value_name = "HOST:PORT")]
    listen: std::net::SocketAddr,
    /// The vehicle (a TOML file, see `sil-host fly --help`); rotorpy's Crazyflie by default.
    #[arg(long, default_value = "vehicles/crazyflie-rotorpy.toml", value_name = "FILE")]
    vehicle: PathBuf,
    /// Hub distance from the centre of the Crazyflie's X, m.
    #[arg(long, default_value_t = 0.043, value_name = "M")]
    hub_m: f64,
    /// Controller: `pd`, `lqr` or `mpc` (the fast MPC at its 1 kHz preset).
    #[arg(long, value_parser = family_parser(), default_value = "mpc")]
    controller: Family,
    /// Form of the controller: `euler` or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    model: AttitudeForm,
    /// The estimator's position source: `mocap` (the SIL's motion capture: position and heading
    /// at 100 Hz) or `external` (only the client's `send_extpos` / `send_extpose`).
    #[arg(long, default_value = "mocap")]
    position_source: String,
    /// Send the plant's true pose (Crazyflie frame, JSON) to this UDP address every 10 ms: a
    /// motion-capture stream for clients and tests.
    #[arg(long, value_name = "HOST:PORT")]
    truth_to: Option<std::net::SocketAddr>,
    /// Stop after this long, s (default: run until killed).
    #[arg(long, value_name = "S")]
    duration: Option<f64>,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Where the vehicle runs: `in-process` (served on --listen), `qemu` (the `firmware-crtp`
    /// image: cflib reaches it through `tools/nrf51_bridge.py` on --syslink) or `qemu-crazyflie`
    /// (the Crazyflie 2.1 image, booted behind QEMU's stand-in for its bootloader, its motors on
    /// TIM2/TIM4).
    #[arg(long, default_value = "in-process", value_parser = ["in-process", "qemu", "qemu-crazyflie"])]
    target: String,
    /// With `--target qemu` or `qemu-crazyflie`: the TCP address of the image's USART6 (syslink), where
    /// `tools/nrf51_bridge.py --syslink` connects.
    #[arg(long, default_value = "127.0.0.1:19880", value_name = "HOST:PORT")]
    syslink: String,
    /// With `--target qemu` or `qemu-crazyflie`: how long the image waits for the bridge to connect, s.
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    bridge_wait: f64,
    /// Fault: every IMU sample in START,LENGTH (s of the plant's time) is NaN; the vehicle flies
    /// the last good one for 10 ms, then descends (its failsafe).
    #[arg(long, value_name = "START,LENGTH", value_parser = parse_window)]
    imu_dead: Option<(f64, f64)>,
    /// Keep persistent parameters in this file, as the vehicle's flash (made if missing; in
    /// process only): cflib's `param.persistent_store` writes the value in force there,
    /// `persistent_clear` forgets it, and the next start flies with what is stored.
    #[arg(long, value_name = "FILE")]
    storage: Option<PathBuf>,
}

#[derive(Args, Debug, Clone)]
struct Px4HilArgs {
    /// The simulator's address.
    #[arg(long, default_value = "127.0.0.1:4560", value_name = "HOST:PORT")]
    connect: String,
    /// Keep trying to connect for this long, s.
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    connect_timeout: f64,
    /// Controller: `pd`, `lqr` or `mpc`.
    #[arg(long, value_parser = family_parser(), default_value = "lqr")]
    controller: Family,
    /// Form of the controller: `euler` or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    model: AttitudeForm,
    /// The vehicle (a TOML file, see `sil-host fly --help`); e.g. vehicles/crazyflie-rotorpy.toml.
    #[arg(long, value_name = "FILE")]
    vehicle: PathBuf,
    /// Rotor layout and motor order (`MOT_FRAME`): `x-rotorpy`, `x-px4` (PX4's quad X), `x-betaflight`
    /// (Betaflight's Quad X, props in), `x-crazyflie` (the Crazyflie's M1–M4), all with hubs at --hub-m
    /// at 45°; or `plus` (the OS4's, at the vehicle's arm). The simulator's motors must be in that order.
    #[arg(long, default_value = "x-rotorpy")]
    airframe: String,
    /// Hub distance from the centre for `x-rotorpy`, m.
    #[arg(long, default_value_t = 0.043, value_name = "M")]
    hub_m: f64,
    /// Motor command unit: `speed` (fraction of the maximum rotor speed, as rotorpy reads it), `thrust` (fraction of the maximum thrust) or `pwm` (1000–2000 µs, linear in speed).
    #[arg(long, default_value = "speed")]
    motor_unit: String,
    /// Where the flight controller runs: `in-process`, or `qemu` (the `firmware-mavlink` image in
    /// QEMU's netduinoplus2, USART1 bridged to the simulator and the ground station; its
    /// parameters are written with PARAM_SET before the flight).
    #[arg(long, default_value = "in-process")]
    target: String,
    /// A ground station's UDP address (QGroundControl's is 127.0.0.1:14550): telemetry is sent
    /// there and its commands, set-points and parameter writes are obeyed.
    #[arg(long, value_name = "HOST:PORT")]
    gcs: Option<std::net::SocketAddr>,
    /// Fly only what the ground station (--gcs) commands: no mission of our own.
    #[arg(long, requires = "gcs", conflicts_with_all = ["waypoints", "scenario"])]
    gcs_only: bool,
    /// Mission: `T,N,E,D` (from T s, hold N, E, D m about home; heading: the one it has at take-off), repeatable, in time order.
    #[arg(long = "waypoint", value_name = "T,N,E,D", required_unless_present_any = ["scenario", "gcs_only"])]
    waypoints: Vec<String>,
    /// Or a scenario's trajectory (`circle`, `helix`, `setpoint`, `eight`; docs/book/src/model.md §9, starting 1 m
    /// above home), flown from --scenario-start s after holding its start point.
    #[arg(long, value_enum, conflicts_with = "waypoints")]
    scenario: Option<ScenarioKind>,
    /// When the scenario starts, s.
    #[arg(long, default_value_t = 3.0, value_name = "S")]
    scenario_start: f64,
    /// Stop after this much simulated time, s.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    duration: f64,
    /// Rate of the position fixes taken from HIL_STATE_QUATERNION, Hz.
    #[arg(long, default_value_t = 100.0, value_name = "HZ")]
    fix_hz: f64,
    /// Set a flight-controller parameter before the flight (`NAME=VALUE`, repeatable, after the
    /// options above; e.g. `PD_ROLL_P=250`, `MPC_W_U=4`; the book's MAVLink chapter lists them). Checked as the
    /// vehicle checks a PARAM_SET: a refused one is an error.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    params: Vec<String>,
    /// Write the trace (t, reported NED, estimated NED, set-point NED) as CSV.
    #[arg(long, value_name = "PATH")]
    csv: Option<PathBuf>,
    /// Write the flight as a ULog (PX4's log format: pyulog, PlotJuggler, Flight Review), as it
    /// flies: the simulator's truth, the estimate, the set-point, the motors, arming, STATUSTEXTs
    /// and the parameters, under PX4's topic names.
    #[arg(long, value_name = "PATH")]
    ulog: Option<PathBuf>,
    /// Keep the vehicle's settings in this file, as its flash (made if missing; in process only):
    /// parameters a ground station sets and the MAVLink signing key are read at the next start
    /// (after --param, which gives the defaults), and the key's timestamp goes on from where it
    /// ended.
    #[arg(long, value_name = "FILE")]
    storage: Option<PathBuf>,
    /// What the controllers fly: `estimate` (the estimator's, from the simulated sensors: the
    /// whole flight controller) or `truth` (the simulator's true state, from its ODOMETRY
    /// messages, once the estimator has aligned: the controller alone, as a peer given perfect
    /// state flies; in process only, a measurement, not a flight mode).
    #[arg(long, default_value = "estimate", value_name = "SOURCE")]
    state: String,
}

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
struct SweepArgs {
    /// `merge`: put shards together (see `sweep merge --help`).
    #[command(subcommand)]
    action: Option<SweepAction>,
    /// Number of true vehicles drawn (each flown by all 8 controller variants).
    #[arg(long, default_value_t = 400, value_name = "N")]
    samples: usize,
    /// Seed of the generator: the same seed draws the same vehicles.
    #[arg(long, default_value_t = 1, value_name = "S")]
    seed: u64,
    /// Mass within ± this percentage of nominal.
    #[arg(long, default_value_t = 20.0, value_name = "PCT")]
    mass_pct: f64,
    /// Each principal inertia within ± this percentage.
    #[arg(long, default_value_t = 30.0, value_name = "PCT")]
    inertia_pct: f64,
    /// Every translational and rotational drag coefficient within ± this percentage.
    #[arg(long, default_value_t = 50.0, value_name = "PCT")]
    drag_pct: f64,
    /// Rotor lag time constant drawn in [0, this] s (0 turns the lag off).
    #[arg(long, default_value_t = 0.2, value_name = "S")]
    lag_max_s: f64,
    /// Rotor thrust coefficient within ± this percentage.
    #[arg(long, default_value_t = 10.0, value_name = "PCT")]
    kf_pct: f64,
    /// Steady horizontal wind up to this speed, m/s, from a random direction.
    #[arg(long, default_value_t = 3.0, value_name = "M_PER_S")]
    wind_max: f64,
    /// Sensor latency drawn in [0, this] ms.
    #[arg(long, default_value_t = 5.0, value_name = "MS")]
    latency_max_ms: f64,
    /// Fly only the slice I of N (samples with index ≡ I mod N) and write it
    /// as DIR/shard-I-of-N.jsonl; `sweep merge` puts the shards together.
    /// For job arrays: `--shard $SLURM_ARRAY_TASK_ID/$COUNT`.
    #[arg(long, value_name = "I/N", value_parser = parse_shard)]
    shard: Option<(usize, usize)>,
    /// A flight succeeds if it never strays farther than this from the reference, m.
    #[arg(long, default_value_t = 1.0, value_name = "M")]
    tube_m: f64,
    /// Scenario flown (docs/book/src/model.md §9 defaults).
    #[arg(long, value_enum, default_value = "helix")]
    scenario: ScenarioKind,
    /// Scenario from a TOML file instead (see `fly --help`).
    #[arg(long, value_name = "FILE")]
    scenario_file: Option<PathBuf>,
    /// Flight length, s.
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    duration: f64,
    /// Nominal vehicle from a TOML file (see `fly --help`); the draws perturb it.
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// Output directory (created if missing).
    #[arg(long, default_value = "sweep", value_name = "DIR")]
    out: PathBuf,
    /// Hide the progress bar.
    #[arg(long)]
    no_progress: bool,
}

#[derive(Subcommand, Debug)]
enum SweepAction {
    /// Merges the shards of one sweep (the *.jsonl files in the given
    /// directories): checks that every sample is there exactly once and
    /// writes the same tables, JSON and figure as a one-machine sweep.
    Merge {
        /// Directories holding shard files.
        #[arg(required = true, value_name = "DIR")]
        dirs: Vec<PathBuf>,
        /// Output directory (created if missing).
        #[arg(long, default_value = "sweep", value_name = "DIR")]
        out: PathBuf,
    },
}

/// `I/N` with N ≥ 1 and I < N.
fn parse_shard(s: &str) -> Result<(usize, usize), String> {
    let (i, n) = s
        .split_once('/')
        .ok_or_else(|| format!("'{s}': expected I/N, e.g. 0/8"))?;
    let (i, n): (usize, usize) = (
        i.trim().parse().map_err(|_| format!("'{i}' is not a shard index"))?,
        n.trim().parse().map_err(|_| format!("'{n}' is not a shard count"))?,
    );
    if n == 0 || i >= n {
        return Err(format!("{i}/{n}: needs N ≥ 1 and 0 ≤ I < N"));
    }
    Ok((i, n))
}

#[derive(Args, Debug)]
struct ReportArgs {
    /// Output directory (created if missing).
    #[arg(long, default_value = "report", value_name = "DIR")]
    out: PathBuf,
    /// Reduced lengths for a fast look (under a minute on 2 cores): circle and helix 30 s, the
    /// horizon sweep 12 s, QEMU flights 0.5 s.
    #[arg(long)]
    quick: bool,
    /// Hide the progress bars.
    #[arg(long)]
    no_progress: bool,
    /// Do not fly the QEMU instructions-per-step table even if qemu-system-arm is installed
    /// (it is marked as skipped in the report).
    #[arg(long)]
    no_qemu: bool,
}

#[derive(Args, Debug)]
struct FlyArgs {
    /// Controller: `pd` (thesis gains, Tables 4.1-4.4), `lqr` (thesis weights, Tables 4.5/4.7)
    /// or `mpc` (linear MPC with the core's QP solver; see --preset).
    #[arg(long, value_parser = family_parser())]
    controller: Family,
    /// MPC preset: `fast` (50 ms prediction steps over 1 s, re-solved at 1 kHz) or `thesis`
    /// (Ts 0.25 s at 4 Hz, N 20, M 2, thesis weights). Other controllers ignore it.
    #[arg(long, value_parser = preset_parser(Family::Mpc), default_value = "fast")]
    preset: Preset,
    /// Form of the controller and of the plant: `euler` or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    model: AttitudeForm,
    /// Scenario (docs/book/src/model.md §9): `setpoint` (step to 3,2,-5 m and 15°), `circle` (R 2 m, 20 s), `helix` (circle climbing 0.05 m/s), `eight` (figure-8, A 1 m, 6 s lap, 20 s; RMSE from the end of the first lap).
    #[arg(long, value_enum, default_value = "setpoint")]
    scenario: ScenarioKind,
    /// Disturbances on the plant: none, wind, mismatch or wind,mismatch (docs/book/src/model.md §9).
    #[arg(long, default_value = "none", value_name = "SET")]
    disturbance: DisturbanceSet,
    /// Sensor noise on the state the controller sees: white, Gaussian, drawn every control step;
    /// SCALE × (5 mm, 2 cm/s, 0.3°, 0.6°/s) on position, velocity, attitude and body rates (1 σ).
    /// The metrics use the true state.
    #[arg(long, value_name = "SCALE")]
    noise: Option<f64>,
    /// Seed of the sensor noise (same seed, same noise), for --noise and for the simulated sensors.
    #[arg(long, default_value_t = 1, value_name = "N")]
    noise_seed: u64,
    /// What the controller flies on: `ekf` (simulated IMU and fixes through the on-board
    /// error-state Kalman filter) or `truth` (the true state, or --noise's version of it).
    /// Default: `ekf`, on every target (IMU and fix messages over the wire, protocol v5 and later); `truth`
    /// where ekf cannot run (controllers slower than 50 Hz, --noise), with a note.
    #[arg(long, value_enum, value_name = "EST")]
    estimator: Option<EstimatorArg>,
    /// Position source of `--estimator ekf`: `mocap` (100 Hz, 2 mm, 10 ms, with heading) or `gps`
    /// (10 Hz, 0.3/0.5 m, velocity, 100 ms; barometer and magnetometer). Default: mocap, or the
    /// scenario file's `[sensors]` table (profile, seed, IMU noise, faults), which these flags
    /// override (`--noise-seed` when not 1).
    #[arg(long, value_enum)]
    sensors: Option<FixProfile>,
    /// Fault: no position fix in START,LENGTH (s).
    #[arg(long, value_name = "START,LENGTH", value_parser = parse_window)]
    fix_outage: Option<(f64, f64)>,
    /// Fault: the first fix at or after S seconds is 5 m off.
    #[arg(long, value_name = "S")]
    fix_outlier_at: Option<f64>,
    /// Fault: the first IMU sample at or after S seconds is NaN.
    #[arg(long, value_name = "S")]
    imu_nan_at: Option<f64>,
    /// Fault: the IMU repeats one sample over START,LENGTH (s).
    #[arg(long, value_name = "START,LENGTH", value_parser = parse_window)]
    imu_stuck: Option<(f64, f64)>,
    /// Fault: a 30 g shock on body z at S seconds clips the accelerometer.
    #[arg(long, value_name = "S")]
    accel_clip_at: Option<f64>,
    /// Circle/helix radius, m (default 2).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    radius: Option<f64>,
    /// Circle/helix period of one revolution, s (default 20).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    period: Option<f64>,
    /// Helix climb rate, m/s of altitude gained (default 0.05).
    #[arg(long, value_name = "M_PER_S", allow_hyphen_values = true)]
    climb_rate: Option<f64>,
    /// Either the set-point target X,Y,Z,YAW_DEG (NED m and heading in degrees; default 3,2,-5,15)
    /// or where the controller runs: `in-process` (default; called directly), `framed` (the
    /// flight-controller core in this process, reached only through the framed wire protocol) or
    /// `tcp:HOST:PORT` (a flight controller behind the protocol, e.g. `sil-host serve`) or `qemu`
    /// (the thumbv7em image in qemu-system-arm's netduinoplus2 over the emulated USART; the JSON
    /// then adds instructions per step; ≈ 4-9 ms of real time per step). Give it twice for both,
    /// e.g. `--target 1,2,-3,45 --target framed`.
    #[arg(long, value_name = "X,Y,Z,YAW_DEG|TARGET", value_parser = parse_target_arg, allow_hyphen_values = true)]
    target: Vec<TargetArg>,
    /// Flight length, s (default 20 for setpoint, 100 for circle and helix).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    duration: Option<f64>,
    /// Reference handling: `feedforward` (reference velocity, and the attitude and thrust its
    /// acceleration implies) or `thesis` (reference position and velocity only, as the thesis).
    #[arg(long, value_parser = reference_parser(), default_value = "feedforward")]
    reference: ReferenceMode,
    /// PD gains: `tuned` (the thesis gains with the roll/pitch and quaternion z corrections
    /// explained in the book's controllers chapter) or `thesis` (Tables 4.1-4.4 as printed). LQR ignores it.
    #[arg(long, value_parser = preset_parser(Family::Pd), default_value = "tuned")]
    gains: Preset,
    /// Controller rate of PD and LQR, Hz [default: 500]. The MPC presets fix their own rate, so
    /// the MPC refuses it; the JSON's `control_hz` is the rate flown.
    #[arg(long, value_name = "HZ", allow_negative_numbers = true)]
    control_hz: Option<f64>,
    /// Plant RK4 rate, Hz (sub-steps within each control period).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ", allow_negative_numbers = true)]
    integration_hz: f64,
    /// Step the flight controller on a simulator's grid, as a simulator that steps at
    /// PERIOD_MS does (rotorpy: 2 ms), each interval PERIOD_MS ± up to JITTER_MS (uniform,
    /// seeded by SEED, default 1), on plant steps (raise --integration-hz for sub-millisecond
    /// grids); the controller runs on its own schedule on those steps and is told each
    /// interval. True-state flights only (--estimator truth).
    #[arg(long, value_name = "PERIOD_MS[,JITTER_MS[,SEED]]", value_parser = parse_step_grid)]
    step_grid: Option<sil_host::flight::StepGrid>,
    /// Vehicle parameters from a TOML file (any subset of mass_kg, gravity_mps2, inertia_kgm2,
    /// arm_m, rotor_inertia_kgm2, kf_ns2, km_nms2, kt_nspm, kr_nms, omega_max_radps, rotor_tau_s,
    /// rotor_gain; the rest stay OS4). Controllers are designed for it and the plant is it.
    #[arg(long, value_name = "FILE")]
    vehicle: Option<PathBuf>,
    /// Scenario from a TOML file (any subset of kind, start_ned_m, start_yaw_deg, target_ned_m,
    /// target_yaw_deg, radius_m, period_s, climb_rate_mps, duration_s; the rest are the docs/book/src/model.md §9
    /// defaults of its kind, --scenario when it names none). Other scenario options then apply
    /// on top of it.
    #[arg(long, value_name = "FILE")]
    scenario_file: Option<PathBuf>,
    /// Write the flight as CSV (one row per 10 ms, state columns then x_ref,y_ref,z_ref,psi_ref).
    #[arg(long, value_name = "PATH")]
    csv: Option<PathBuf>,
    /// Write the metrics as JSON (`-` for standard output).
    #[arg(long, value_name = "PATH")]
    json: Option<PathBuf>,
    /// Write the flight as a ULog (PX4's log format: pyulog, PlotJuggler, Flight Review), as it
    /// flies, every 10 ms: the plant's truth (PX4's ground-truth topics), the estimate, the
    /// reference, the motors and the flight's parameters, under PX4's topic names.
    #[arg(long, value_name = "PATH")]
    ulog: Option<PathBuf>,
    /// With `--target qemu`: print the firmware's own log (defmt over semihosting, decoded with
    /// the image's format table) to standard error after the flight.
    #[arg(long)]
    firmware_log: bool,
    /// Over a link (framed, tcp, qemu): send N parameter reads with every step, right after its
    /// sample, as a ground station flooding the flight controller would (at most 16); their
    /// answers are dropped. With `--target qemu --firmware-log`, the image's timing line shows
    /// what the flood cost its tasks.
    #[arg(long, value_name = "N", default_value_t = 0)]
    param_flood: u16,
}

#[derive(Args, Debug)]
struct ServeArgs {
    /// Address to listen on, HOST:PORT (e.g. 127.0.0.1:7000).
    #[arg(long, value_name = "HOST:PORT")]
    listen: String,
    /// End a session after this many seconds without a valid frame, or when
    /// the client has not read its replies for that long.
    #[arg(long, default_value_t = 10.0, value_name = "S", allow_negative_numbers = true)]
    idle_timeout: f64,
    /// End any session after this many seconds, however busy (one client
    /// cannot hold the only slot forever).
    #[arg(long, default_value_t = 7200.0, value_name = "S", allow_negative_numbers = true)]
    max_session: f64,
    /// Stop after this many client sessions (default: serve forever).
    #[arg(long, value_name = "N")]
    max_clients: Option<usize>,
}

#[derive(Args, Debug)]
struct MpcStepArgs {
    /// Form of the MPC and the plant.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    model: AttitudeForm,
    /// MPC preset: `fast` or `thesis`.
    #[arg(long, value_parser = preset_parser(Family::Mpc), default_value = "fast")]
    preset: Preset,
    /// Scenario flown up to --at.
    #[arg(long, value_enum, default_value = "setpoint")]
    scenario: ScenarioKind,
    /// Time of the step to explain, s (the last MPC step at or before it).
    #[arg(long, value_name = "T")]
    at: f64,
    /// Disturbances on the plant: none, wind, mismatch or wind,mismatch.
    #[arg(long, default_value = "none", value_name = "SET")]
    disturbance: DisturbanceSet,
    /// Print JSON (the only output format; accepted for clarity).
    #[arg(long)]
    json: bool,
}

#[derive(Args, Debug)]
struct DesignArgs {
    #[command(subcommand)]
    what: DesignWhat,
}

#[derive(Subcommand, Debug)]
enum DesignWhat {
    /// Continuous-time LQR about hover at a heading: prints {"A","B","Q","R","K"} (row-major) with U = Uss - K dX.
    Lqr(DesignLqrArgs),
}

#[derive(Args, Debug)]
struct DesignLqrArgs {
    /// Form: `euler` (12 states, weights Table 4.5) or `quaternion` (reduced 12 states, Q = I, R = I).
    #[arg(long, value_parser = form_parser())]
    model: AttitudeForm,
    /// Hover heading psi_T the model is linearised about, degrees.
    #[arg(long, default_value_t = 0.0, value_name = "DEG", allow_hyphen_values = true)]
    yaw_deg: f64,
    /// Print JSON (the only output format; accepted for clarity).
    #[arg(long)]
    json: bool,
    /// The LQR the flight controller flies instead: the project's weights,
    /// the inputs weighted for the vehicle, designed in discrete time at
    /// --period-s (prints A, B, Q, R, ts_s and the discrete K).
    #[arg(long)]
    flown: bool,
    /// With --flown: the vehicle from a TOML file (see `fly --help`); the OS4 if not given.
    #[arg(long, value_name = "FILE", requires = "flown")]
    vehicle: Option<PathBuf>,
    /// With --flown: the control period, s (the flight loop flies the LQR every 2 ms).
    #[arg(long, default_value_t = 0.002, value_name = "S", requires = "flown")]
    period_s: f64,
}

/// Options shared by every command that builds a plant.
#[derive(Args, Debug, Clone)]
struct PlantArgs {
    /// Equations the plant integrates: `euler` (ZYX angles, singular at 90° pitch) or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    model: AttitudeForm,
    /// RK4 integration rate of the plant, Hz (each control period is cut into sub-steps at this rate).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ", allow_negative_numbers = true)]
    integration_hz: f64,
    /// Turn on the first-order rotor lag (tau = 0.178 s, gain 0.936, docs/book/src/model.md §6).
    #[arg(long)]
    rotor_lag: bool,
    /// Disturbances acting on the plant: none, wind, mismatch or wind,mismatch (docs/book/src/model.md §9).
    #[arg(long, default_value = "none", value_name = "SET")]
    disturbance: DisturbanceSet,
}

impl PlantArgs {
    fn config(&self) -> Result<PlantConfig> {
        let (ih, max) = (self.integration_hz, sil_host::flight::MAX_INTEGRATION_HZ);
        if !(ih.is_finite() && (1.0..=max).contains(&ih)) {
            bail!("--integration-hz {ih:?} is out of range: must be in [1, {max}] Hz");
        }
        let mut cfg = PlantConfig::nominal(self.model);
        cfg.integration_hz = self.integration_hz;
        cfg.rotor_lag = self.rotor_lag;
        Ok(cfg.with_disturbance(self.disturbance))
    }
}

#[derive(Args, Debug)]
struct OpenLoopArgs {
    #[command(flatten)]
    plant: PlantArgs,
    /// Constant commanded input U1,U2,U3,U4: thrust N, roll force N, pitch force N, yaw torque N·m.
    /// Goes through the mixer inverse and rotor clamping (realised inputs are in the CSV).
    #[arg(long, value_name = "U1,U2,U3,U4", value_parser = parse_list::<4>, allow_hyphen_values = true)]
    u: [f64; 4],
    /// Length of the flight, s.
    #[arg(long, default_value_t = 3.0, value_name = "SECONDS")]
    duration: f64,
    /// Start position X,Y,Z in NED metres (hovering at rest, level).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_list::<3>, allow_hyphen_values = true, default_value = "0,0,-1")]
    start: [f64; 3],
    /// Start heading, degrees.
    #[arg(long, default_value_t = 0.0, value_name = "DEG", allow_negative_numbers = true)]
    yaw_deg: f64,
    /// Output CSV, one row per 10 ms: t,x,y,z,vx,vy,vz,q0,q1,q2,q3,phi,theta,psi,p,q,r,u1,u2,u3,u4.
    /// Without it the last row is printed.
    #[arg(long, value_name = "PATH")]
    csv: Option<PathBuf>,
}

/// A `--target` value of `fly`: a set-point or an execution target.
#[derive(Debug, Clone)]
enum TargetArg {
    /// X, Y, Z (NED m), heading (deg).
    Setpoint([f64; 4]),
    /// Where the controller runs.
    Exec(Target),
}

fn parse_step_grid(s: &str) -> Result<sil_host::flight::StepGrid, String> {
    let v: Vec<&str> = s.split(',').map(str::trim).collect();
    if v.is_empty() || v.len() > 3 {
        return Err(format!("'{s}' is not PERIOD_MS[,JITTER_MS[,SEED]]"));
    }
    let ms = |x: &str| {
        x.parse::<f64>()
            .map_err(|_| format!("'{x}' is not a number of milliseconds"))
    };
    let grid = sil_host::flight::StepGrid {
        period_s: ms(v[0])? * 1e-3,
        jitter_s: v.get(1).map_or(Ok(0.0), |x| ms(x))? * 1e-3,
        seed: v
            .get(2)
            .map_or(Ok(1), |x| x.parse::<u64>().map_err(|_| format!("'{x}' is not a seed")))?,
    };
    grid.validate().map_err(|e| e.to_string())?;
    Ok(grid)
}

fn parse_target_arg(s: &str) -> Result<TargetArg, String> {
    if let Ok(v) = parse_list::<4>(s) {
        return Ok(TargetArg::Setpoint(v));
    }
    s.parse::<Target>()
        .map(TargetArg::Exec)
        .map_err(|e| format!("{e}, or X,Y,Z,YAW_DEG for a set-point"))
}

/// Parses `N` comma-separated finite numbers, e.g. `6.4765,0.001,0,0.01`.
/// A clap parser for one of the core's named values, from `(spelling, value)`
/// pairs the core's tables give (so the command line cannot spell a name
/// differently from the JSON, the tables and the wire).
fn named<T: Copy + Send + Sync + 'static>(pairs: Vec<(&'static str, T)>) -> impl TypedValueParser<Value = T> {
    let names: Vec<&'static str> = pairs.iter().map(|(n, _)| *n).collect();
    PossibleValuesParser::new(names).try_map(move |s: String| {
        pairs
            .iter()
            .find(|(n, _)| *n == s)
            .map(|(_, v)| *v)
            .ok_or_else(|| format!("unknown value '{s}'"))
    })
}

fn family_parser() -> impl TypedValueParser<Value = Family> {
    named(Family::ALL.iter().map(|f| (f.name(), *f)).collect())
}

fn form_parser() -> impl TypedValueParser<Value = AttitudeForm> {
    named(AttitudeForm::ALL.iter().map(|f| (f.name(), *f)).collect())
}

fn reference_parser() -> impl TypedValueParser<Value = ReferenceMode> {
    named(ReferenceMode::ALL.iter().map(|m| (m.name(), *m)).collect())
}

/// The presets of `family` by their own names (`tuned`/`thesis` gains for
/// PD, `fast`/`thesis` for the MPC), from the spec table.
fn preset_parser(family: Family) -> impl TypedValueParser<Value = Preset> {
    let mut pairs: Vec<(&'static str, Preset)> = Vec::new();
    for r in SPECS.iter().filter(|r| r.family == family) {
        if !pairs.iter().any(|(n, _)| *n == r.preset_name) {
            pairs.push((r.preset_name, r.preset));
        }
    }
    named(pairs)
}

fn parse_list<const N: usize>(s: &str) -> Result<[f64; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!("expected {N} comma-separated numbers, got {}", parts.len()));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p.parse::<f64>().map_err(|e| format!("'{p}': {e}"))?;
        if !o.is_finite() {
            return Err(format!("'{p}' is not a finite number"));
        }
    }
    Ok(out)
}

fn open_loop(a: &OpenLoopArgs) -> Result<()> {
    let max = sil_host::scenario::LIMITS.duration_s;
    if !(a.duration.is_finite() && a.duration > 0.0 && a.duration <= max) {
        bail!("--duration {:?} is out of range: must be in (0, {max}] s", a.duration);
    }
    let run = OpenLoop {
        plant: a.plant.config()?,
        u: nalgebra::Vector4::from(a.u),
        start_ned_m: a.start,
        start_yaw_rad: a.yaw_deg.to_radians(),
        duration_s: a.duration,
    };
    // Rows go straight to the file (a long run never sits in memory); the
    // run returns its last row for the summary.
    let last = match &a.csv {
        Some(path) => {
            let mut sink = CsvSink::create(path, false)?;
            let last = run.run_into(&mut sink)?;
            let n = sink.finish()?;
            eprintln!("wrote {n} rows to {}", path.display());
            last
        }
        None => run.run_into(&mut Discard)?,
    };
    for (name, v) in STATE_COLUMNS.iter().zip(last.iter()) {
        print!("{name}={v:.6} ");
    }
    println!();
    Ok(())
}

fn scenario_from(a: &FlyArgs) -> Result<Scenario> {
    let mut sc = match &a.scenario_file {
        Some(f) => sil_host::config::load_scenario(f, a.scenario)?,
        None => Scenario::default_for(a.scenario),
    };
    if let Some(r) = a.radius {
        sc.radius_m = r;
    }
    if let Some(p) = a.period {
        sc.period_s = p;
    }
    if let Some(v) = a.climb_rate {
        sc.climb_rate_mps = v;
    }
    for t in &a.target {
        if let TargetArg::Setpoint([x, y, z, yaw]) = t {
            sc.target_ned_m = [*x, *y, *z];
            sc.target_yaw_rad = yaw.to_radians();
        }
    }
    if let Some(d) = a.duration {
        sc.duration_s = d;
    }
    sc.validate().map_err(anyhow::Error::msg)?;
    Ok(sc)
}

fn write_json(path: &PathBuf, value: &serde_json::Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    if path.as_os_str() == "-" {
        println!("{text}");
    } else {
        std::fs::write(path, text + "\n").with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}

/// What the controller flies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
enum EstimatorArg {
    /// Simulated sensors through the on-board estimator.
    Ekf,
    /// The true state.
    Truth,
}

fn parse_window(s: &str) -> Result<(f64, f64), String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("'{x}': {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [a, b] if a.is_finite() && b.is_finite() && a >= 0.0 && b > 0.0 => Ok((a, b)),
        _ => Err(format!("'{s}': need START,LENGTH in s with START ≥ 0 and LENGTH > 0")),
    }
}

/// The sensors of a `fly`, or `None` for a truth flight (with a note when
/// the default had to fall back to it).
fn sensors_for(a: &FlyArgs, cfg: &FlightConfig) -> Result<Option<SensorConfig>> {
    let faults = sil_host::sensors::Faults {
        outage: a.fix_outage,
        outlier_at_s: a.fix_outlier_at,
        imu_nan_at_s: a.imu_nan_at,
        imu_stuck: a.imu_stuck,
        imu_dead: None,
        accel_clip_at_s: a.accel_clip_at,
    };
    for (flag, v) in [
        ("--fix-outlier-at", a.fix_outlier_at),
        ("--imu-nan-at", a.imu_nan_at),
        ("--accel-clip-at", a.accel_clip_at),
    ] {
        if v.is_some_and(|t| !(t.is_finite() && t >= 0.0)) {
            bail!("{flag} must be a time ≥ 0 s");
        }
    }
    let faulty = faults != sil_host::sensors::Faults::default();
    let why_not = cfg.noise.is_some().then_some("--noise perturbs the true state");
    match (a.estimator, why_not) {
        (Some(EstimatorArg::Truth), _) => {
            if faulty {
                bail!("sensor faults need --estimator ekf");
            }
            Ok(None)
        }
        (Some(EstimatorArg::Ekf), Some(why)) => bail!("--estimator ekf cannot fly here: {why}"),
        (None, Some(why)) => {
            if faulty {
                bail!("sensor faults need --estimator ekf, which cannot fly here: {why}");
            }
            eprintln!("note: flying the true state: {why}");
            Ok(None)
        }
        (_, None) => {
            // The scenario file's [sensors] first, the flags over it.
            let file = match &a.scenario_file {
                Some(f) => sil_host::config::load_sensors(f)?,
                None => None,
            };
            let mut sc = file.unwrap_or_else(|| SensorConfig::new(FixProfile::Mocap, a.noise_seed));
            if let Some(p) = a.sensors {
                sc.profile = p;
            }
            if a.noise_seed != 1 || file.is_none() {
                sc.seed = a.noise_seed;
            }
            let f = &mut sc.faults;
            f.outage = faults.outage.or(f.outage);
            f.outlier_at_s = faults.outlier_at_s.or(f.outlier_at_s);
            f.imu_nan_at_s = faults.imu_nan_at_s.or(f.imu_nan_at_s);
            f.imu_stuck = faults.imu_stuck.or(f.imu_stuck);
            f.accel_clip_at_s = faults.accel_clip_at_s.or(f.accel_clip_at_s);
            Ok(Some(sc))
        }
    }
}

fn fly_cmd(a: &FlyArgs) -> Result<()> {
    let mut cfg = FlightConfig::new(a.controller, a.model, scenario_from(a)?);
    cfg.disturbance = a.disturbance;
    cfg.noise = a
        .noise
        .map(|k| sil_host::noise::SensorNoise::typical(k, a.noise_seed))
        .transpose()
        .context("--noise")?;
    cfg.spec.reference = a.reference;
    // PD takes its gain set from --gains, the MPC its preset from --preset.
    cfg.spec.preset = match a.controller {
        Family::Pd => a.gains,
        Family::Mpc => a.preset,
        Family::Lqr => Preset::Project,
    };
    cfg.control_hz = match (a.controller, a.control_hz) {
        (Family::Mpc, Some(hz)) => bail!(
            "--control-hz {hz}: the MPC's preset fixes its own rate ({} Hz for --preset {}); \
             --control-hz sets PD's and LQR's",
            1.0 / cfg.spec.period_s(0.002),
            cfg.spec.row().preset_name
        ),
        (_, hz) => hz.unwrap_or(500.0),
    };
    if let Some(f) = &a.vehicle {
        cfg.vehicle = sil_host::config::load_vehicle(f)?;
    }
    if !(a.integration_hz.is_finite() && a.integration_hz >= 1.0) {
        bail!("--integration-hz must be at least 1 Hz");
    }
    cfg.integration_hz = a.integration_hz;
    cfg.step_grid = a.step_grid;
    cfg.param_flood = a.param_flood;
    let exec = a
        .target
        .iter()
        .rev()
        .find_map(|t| {
            if let TargetArg::Exec(e) = t {
                Some(e.clone())
            } else {
                None
            }
        })
        .unwrap_or(Target::InProcess);
    cfg.sensors = sensors_for(a, &cfg)?;
    // Remote flights take real time (QEMU: milliseconds a step): show progress.
    let bar = sil_host::study::progress_bar(
        (cfg.scenario.duration_s * 10.0).round() as usize,
        "× 0.1 s flown",
        exec != Target::InProcess && std::io::stderr().is_terminal(),
    );
    bar.set_message(format!("{exec:?}"));
    let tick = |t: f64| bar.set_position((t * 10.0) as u64);
    // The rows go to the CSV file as they are flown, or nowhere: the CLI
    // reports metrics, which are computed online, so no flight of any
    // length is held in memory.
    let mut csv = a.csv.as_deref().map(|p| CsvSink::create(p, true)).transpose()?;
    let mut ulog = match &a.ulog {
        Some(p) => {
            let mut settings = fc_loop::params::Settings::os4();
            settings.vehicle = cfg.vehicle.cast();
            settings.controller = cfg.spec;
            Some(FlyULog::create(p, &settings, cfg.vehicle, cfg.sensors.is_none())?)
        }
        None => None,
    };
    let mut tee;
    let rec = match (csv.as_mut(), ulog.as_mut()) {
        (Some(c), Some(u)) => {
            tee = Tee(c, u);
            Recording::Stream(&mut tee)
        }
        (Some(c), None) => Recording::Stream(c),
        (None, Some(u)) => Recording::Stream(u),
        (None, None) => Recording::Stream(&mut Discard),
    };
    let res = sil_host::flight::fly_target_with_progress(&cfg, &exec, Some(&tick), rec);
    bar.finish_and_clear();
    let res = res?;
    if let Some(sink) = csv {
        sink.finish()?;
    }
    if let Some(mut log) = ulog {
        let end = cfg.scenario.duration_s;
        for l in &res.firmware_log {
            sil_host::record::RowSink::log(&mut log, end, l)?;
        }
        log.finish()?;
    }
    if a.firmware_log {
        for l in &res.firmware_log {
            eprintln!("firmware: {l}");
        }
    }
    let json = sil_host::report::flight_json(&cfg, &res);
    if let Some(path) = &a.json {
        write_json(path, &json)?;
    }
    if a.json.as_ref().is_none_or(|p| p.as_os_str() != "-") {
        println!("{}", sil_host::report::flight_summary(&cfg, &res));
    }
    Ok(())
}

fn design_cmd(a: &DesignArgs) -> Result<()> {
    match &a.what {
        DesignWhat::Lqr(d) => {
            if !d.yaw_deg.is_finite() {
                bail!("--yaw-deg must be finite");
            }
            let v = if d.flown {
                if !(d.period_s.is_finite() && d.period_s > 0.0) {
                    bail!("--period-s must be a positive number of seconds");
                }
                let p = match &d.vehicle {
                    Some(f) => sil_host::config::load_vehicle(f)?,
                    None => fc_core::VehicleParams::OS4,
                };
                sil_host::report::lqr_flown_design_json(d.model, d.yaw_deg.to_radians(), &p, d.period_s)?
            } else {
                sil_host::report::lqr_design_json(d.model, d.yaw_deg.to_radians())?
            };
            println!("{}", serde_json::to_string_pretty(&v)?);
            Ok(())
        }
    }
}

fn mpc_step_cmd(a: &MpcStepArgs) -> Result<()> {
    let sc = Scenario::default_for(a.scenario);
    if !(a.at.is_finite() && a.at >= 0.0 && a.at <= sc.duration_s) {
        bail!("--at must be within the scenario's 0..{} s", sc.duration_s);
    }
    let mut cfg = FlightConfig::new(Family::Mpc, a.model, sc);
    cfg.spec.preset = a.preset;
    cfg.disturbance = a.disturbance;
    let (_, ctrl) = sil_host::flight::fly_until(&cfg, Some(a.at), |_, _| {})?;
    let v = sil_host::report::mpc_step_json(&ctrl, a.at).ok_or_else(|| anyhow::anyhow!("no MPC step was taken"))?;
    println!("{}", serde_json::to_string_pretty(&v)?);
    Ok(())
}

fn report_cmd(a: &ReportArgs) -> Result<()> {
    let w = sil_host::full_report::write_report(&sil_host::full_report::ReportOptions {
        out: a.out.clone(),
        quick: a.quick,
        progress: !a.no_progress,
        qemu: !a.no_qemu,
    })?;
    eprintln!(
        "wrote {} and {} ({} flights, {} figure files, {:.1} s)",
        w.index_md.display(),
        w.index_html.display(),
        w.flights,
        w.figures.len(),
        w.seconds
    );
    Ok(())
}

fn sweep_cmd(a: &SweepArgs) -> Result<()> {
    let t0 = std::time::Instant::now();
    let (o, rows) = match &a.action {
        Some(SweepAction::Merge { dirs, out }) => {
            sil_host::record::prepare_output_dir(out)?;
            sil_host::sweep::merge(dirs, out.clone())?
        }
        None => {
            let mut base = match &a.scenario_file {
                Some(f) => sil_host::config::load_scenario(f, a.scenario)?,
                None => Scenario::default_for(a.scenario),
            };
            if a.scenario_file.is_none() {
                base.duration_s = a.duration;
            }
            base.validate().map_err(anyhow::Error::msg)?;
            let o = sil_host::sweep::SweepOptions {
                samples: a.samples,
                seed: a.seed,
                mass_frac: a.mass_pct / 100.0,
                inertia_frac: a.inertia_pct / 100.0,
                drag_frac: a.drag_pct / 100.0,
                lag_max_s: a.lag_max_s,
                kf_frac: a.kf_pct / 100.0,
                wind_max_mps: a.wind_max,
                latency_max_s: a.latency_max_ms / 1e3,
                tube_m: a.tube_m,
                base,
                vehicle: match &a.vehicle {
                    Some(f) => sil_host::config::load_vehicle(f)?,
                    None => fc_core::VehicleParams::OS4,
                },
                out: a.out.clone(),
                progress: !a.no_progress,
            };
            if let Some(shard) = a.shard {
                let path = sil_host::sweep::run_shard(&o, shard)?;
                eprintln!("wrote {} ({:.1} s)", path.display(), t0.elapsed().as_secs_f64());
                return Ok(());
            }
            let rows = sil_host::sweep::run(&o)?;
            (o, rows)
        }
    };
    let path = sil_host::sweep::write(&o, &rows)?;
    for r in &rows {
        let p = r.rmse_percentiles_m;
        println!(
            "{:<22} success {:5.1} %  RMSE p50 {:.3} p90 {:.3} p99 {:.3} max {:.3} m",
            r.controller, r.success_pct, p[0], p[1], p[2], p[3]
        );
    }
    eprintln!("wrote {} ({:.1} s)", path.display(), t0.elapsed().as_secs_f64());
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match &cli.command {
        Command::OpenLoop(a) => open_loop(a),
        Command::Fly(a) => fly_cmd(a),
        Command::Design(a) => design_cmd(a),
        Command::Report(a) => report_cmd(a),
        Command::Sweep(a) => sweep_cmd(a),
        Command::MpcStep(a) => mpc_step_cmd(a),
        Command::Px4Hil(a) => px4_hil(a.clone()),
        Command::Crtp(a) => crtp_cmd(a),
        Command::Plot(a) => {
            let tracks = sil_host::ulog_plot::read_tracks(&a.ulog)?;
            let stem = a
                .ulog
                .file_stem()
                .map_or("ulog".into(), |s| s.to_string_lossy().into_owned());
            std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
            for fig in sil_host::ulog_plot::figures(&stem, &tracks) {
                sil_host::figures::write(&a.out, &fig)?;
                println!("wrote {}/{}.svg and .png", a.out.display(), fig.stem);
            }
            println!(
                "{} samples of {}, {} set-points",
                tracks.flown.len(),
                tracks.source,
                tracks.setpoint.len()
            );
            Ok(())
        }
        Command::MarkdownHelp => {
            let opts = clap_markdown::MarkdownOptions::new()
                .title("Command-line reference".to_string())
                .show_footer(false);
            print!("{}", clap_markdown::help_markdown_custom::<Cli>(&opts));
            Ok(())
        }
        Command::Serve(a) => {
            for (flag, v) in [("--idle-timeout", a.idle_timeout), ("--max-session", a.max_session)] {
                if !(v.is_finite() && v > 0.0 && v <= 1e6) {
                    bail!("{flag} {v:?} is out of range: must be in (0, 1e6] s");
                }
            }
            let listener = std::net::TcpListener::bind(&a.listen).with_context(|| format!("binding {}", a.listen))?;
            eprintln!("serve: listening on {}", listener.local_addr()?);
            sil_host::link::serve(
                listener,
                &sil_host::link::ServeOptions {
                    idle: std::time::Duration::from_secs_f64(a.idle_timeout),
                    max_session: std::time::Duration::from_secs_f64(a.max_session),
                    max_clients: a.max_clients,
                    log: true,
                },
            )
        }
    }
}

fn crtp_cmd(a: &CrtpArgs) -> Result<()> {
    use fc_loop::params::{Airframe, Settings};
    let vehicle = sil_host::config::load_vehicle(&a.vehicle)?;
    let mut settings = Settings::os4();
    settings.vehicle = vehicle.cast();
    settings.airframe = Airframe::XCrazyflie;
    settings.hub_m = a.hub_m as f32;
    settings.controller = fc_core::control::ControllerSpec::new(a.controller, a.model);
    settings
        .check()
        .map_err(|e| anyhow::anyhow!("the vehicle's settings are refused: {e} (--hub-m, --vehicle)"))?;
    let position_source = match a.position_source.as_str() {
        "mocap" => sil_host::crtp::PositionSource::Mocap,
        "external" => sil_host::crtp::PositionSource::External,
        other => bail!("unknown --position-source '{other}': use mocap or external"),
    };
    if let Some(d) = a.duration {
        if !(d.is_finite() && d > 0.0 && d <= 1e6) {
            bail!("--duration {d:?} is out of range: must be in (0, 1e6] s");
        }
    }
    if !(a.bridge_wait.is_finite() && a.bridge_wait >= 1.0 && a.bridge_wait <= 3600.0) {
        bail!(
            "--bridge-wait {:?} is out of range: must be in [1, 3600] s",
            a.bridge_wait
        );
    }
    // SIGINT/SIGTERM end the flight at the next step: the summary is written
    // and QEMU (with --target qemu) stopped, not left orphaned.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
        .context("installing the SIGINT/SIGTERM handler")?;
    let summary = sil_host::crtp::run(&sil_host::crtp::CrtpConfig {
        stop,
        listen: a.listen,
        settings,
        vehicle,
        position_source,
        truth_to: a.truth_to,
        duration_s: a.duration,
        seed: a.seed,
        imu_dead: a.imu_dead,
        storage: a.storage.clone(),
        target: match a.target.as_str() {
            "qemu" | "qemu-crazyflie" => sil_host::crtp::CrtpTarget::Qemu {
                syslink: a.syslink.clone(),
                wait_s: a.bridge_wait,
                crazyflie: a.target == "qemu-crazyflie",
            },
            _ => sil_host::crtp::CrtpTarget::InProcess,
        },
    })?;
    println!("{}", serde_json::to_string_pretty(&summary)?);
    Ok(())
}

fn px4_hil(a: Px4HilArgs) -> Result<()> {
    use fc_core::model::airframe::MotorUnit;
    use fc_mavlink::params::{Airframe, Settings};
    let vehicle = sil_host::config::load_vehicle(&a.vehicle)?;
    let mut settings = Settings::os4();
    settings.vehicle = vehicle.cast();
    (settings.airframe, settings.hub_m) = match a.airframe.as_str() {
        "x-rotorpy" => (Airframe::XRotorpy, a.hub_m as f32),
        "x-px4" => (Airframe::XPx4, a.hub_m as f32),
        "x-betaflight" => (Airframe::XBetaflight, a.hub_m as f32),
        "x-crazyflie" => (Airframe::XCrazyflie, a.hub_m as f32),
        "plus" => (Airframe::Plus, vehicle.arm_m as f32),
        other => bail!("unknown --airframe '{other}': use x-rotorpy, x-px4, x-betaflight, x-crazyflie or plus"),
    };
    settings.unit = match a.motor_unit.as_str() {
        "speed" => MotorUnit::SpeedFraction,
        "thrust" => MotorUnit::ThrustFraction,
        "pwm" => MotorUnit::PwmUs {
            min_us: 1000,
            max_us: 2000,
        },
        other => bail!("unknown --motor-unit '{other}': use speed, thrust or pwm"),
    };
    settings.controller = fc_core::control::ControllerSpec::new(a.controller, a.model);
    if !(a.fix_hz.is_finite() && (1.0..=1000.0).contains(&a.fix_hz)) {
        bail!("--fix-hz {:?} is out of range: must be in [1, 1000]", a.fix_hz);
    }
    settings.fix_period_ms = (1000.0 / a.fix_hz).round() as u32;
    settings
        .check()
        .map_err(|e| anyhow::anyhow!("the vehicle's settings are refused: {e} (--hub-m, --vehicle)"))?;
    for p in &a.params {
        let Some((name, value)) = p.split_once('=') else {
            bail!("--param '{p}' is not NAME=VALUE");
        };
        let index = fc_mavlink::params::index_of(name.trim().as_bytes())
            .ok_or_else(|| anyhow::anyhow!("--param '{p}': no parameter is named '{}'", name.trim()))?;
        let value: f32 = value
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("--param '{p}': '{}' is not a number", value.trim()))?;
        settings = fc_mavlink::params::write(&settings, index, value)
            .map_err(|e| anyhow::anyhow!("--param '{p}' is refused: {e}"))?;
    }
    let mut mission = Vec::new();
    for w in &a.waypoints {
        let v: Vec<f64> = w
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| anyhow::anyhow!("--waypoint '{w}' is not T,N,E,D (numbers)"))?;
        let [t, n, e, d] = v[..] else {
            bail!("--waypoint '{w}' is not T,N,E,D (four numbers)");
        };
        if !v.iter().all(|x| x.is_finite()) || t < 0.0 || v[1..].iter().any(|x| x.abs() > 1000.0) {
            bail!("--waypoint '{w}': time must be ≥ 0 and positions within 1 km");
        }
        if mission.last().is_some_and(|p: &sil_host::hil::Waypoint| p.at_s > t) {
            bail!("--waypoint '{w}' is earlier than the one before: give them in time order");
        }
        mission.push(sil_host::hil::Waypoint {
            at_s: t,
            pos_ned_m: [n, e, d],
            yaw_rad: 0.0,
        });
    }
    let mission = match a.scenario {
        _ if a.gcs_only => None,
        Some(kind) => {
            if !(a.scenario_start.is_finite() && (0.0..=1e5).contains(&a.scenario_start)) {
                bail!("--scenario-start {:?} must be in [0, 1e5] s", a.scenario_start);
            }
            let sc = Scenario::default_for(kind);
            sc.validate().map_err(anyhow::Error::msg)?;
            sc.check_feasible(&vehicle).map_err(anyhow::Error::msg)?;
            Some(sil_host::hil::Mission::Scenario {
                scenario: sc,
                from_s: a.scenario_start,
            })
        }
        None => Some(sil_host::hil::Mission::Waypoints(mission)),
    };
    for (flag, v) in [("--duration", a.duration), ("--connect-timeout", a.connect_timeout)] {
        if !(v.is_finite() && v > 0.0 && v <= 1e5) {
            bail!("{flag} {v:?} is out of range: must be in (0, 1e5]");
        }
    }
    let cfg = sil_host::hil::HilConfig {
        addr: a.connect,
        connect_timeout_s: a.connect_timeout,
        settings,
        mission,
        gcs: a.gcs,
        duration_s: a.duration,
        ulog: a.ulog.clone(),
        storage: a.storage.clone(),
        truth_state: match (a.state.as_str(), a.target.as_str()) {
            ("estimate", _) => false,
            ("truth", "in-process") => true,
            ("truth", _) => {
                bail!("--state truth flies the flight controller in this process only (the image flies its estimate)")
            }
            (other, _) => bail!("unknown --state '{other}': use estimate or truth"),
        },
        target: match a.target.as_str() {
            "in-process" => sil_host::hil::Target::InProcess,
            "qemu" => sil_host::hil::Target::Qemu(sil_host::link::firmware_mavlink_elf()?),
            other => bail!("unknown --target '{other}': use in-process or qemu"),
        },
    };
    let res = sil_host::hil::run(&cfg)?;
    if let Some(path) = &a.csv {
        let mut w = csv::Writer::from_path(path)?;
        w.write_record([
            "t",
            "north",
            "east",
            "down",
            "est_north",
            "est_east",
            "est_down",
            "sp_north",
            "sp_east",
            "sp_down",
        ])?;
        for r in &res.trace {
            w.write_record(r.iter().map(|v| v.to_string()))?;
        }
        w.flush()?;
    }
    eprintln!("px4-hil: the flight ended: {}", res.end);
    println!("{}", serde_json::to_string_pretty(&res)?);
    Ok(())
}
