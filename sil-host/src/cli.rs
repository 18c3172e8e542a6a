//! The command line: `sil-host`'s subcommands and their options (clap),
//! and the parsers of their values.

use anyhow::{bail, Result};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand};
use fc_core::control::{Family, Preset, ReferenceMode, SPECS};
use fc_core::AttitudeForm;
use sil_host::disturbance::DisturbanceSet;
use sil_host::flight::Target;
use sil_host::plant::PlantConfig;
use sil_host::scenario::ScenarioKind;
use sil_host::sensors::FixProfile;
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
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Command,
}

#[derive(Subcommand, Debug)]
pub(crate) enum Command {
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
pub(crate) struct PlotArgs {
    /// The ULog to draw.
    #[arg(long, value_name = "FILE")]
    pub(crate) ulog: PathBuf,
    /// Output directory for DIR/STEM_position.svg|png and DIR/STEM_path_top.svg|png (created if
    /// missing); STEM is the log's file name.
    #[arg(long, default_value = "figures", value_name = "DIR")]
    pub(crate) out: PathBuf,
}

#[derive(Args, Debug, Clone)]
pub(crate) struct CrtpArgs {
    /// The UDP address to listen on (cflib scans ports 19850–19859 of 127.0.0.1); with
    /// `--count N`, vehicle i listens on its port + i.
    #[arg(long, default_value = "127.0.0.1:19850", value_name = "HOST:PORT")]
    pub(crate) listen: std::net::SocketAddr,
    /// Report this deck attached in its `deck.<NAME>` flag (repeatable; in process): `bcFlow2`
    /// or `bcLighthouse4` for a script that waits for a positioning deck. A stand-in: no deck is
    /// simulated, the position still comes from the SIL's motion capture (--position-source).
    #[arg(long, value_name = "NAME", value_parser = fc_crtp::vehicle::DECK_NAMES)]
    pub(crate) deck: Vec<String>,
    /// Fly N vehicles in one simulated world (1–16, in process): each its own flight stack,
    /// sensors and UDP port, for cflib's `Swarm`. Vehicles whose rotor discs meet both fall.
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub(crate) count: usize,
    /// Where a vehicle starts on the ground, Crazyflie frame (x forward, y left), m: once per
    /// vehicle, in order (default: rows of four, 1 m apart, the first at the origin).
    #[arg(long = "at", value_name = "X,Y", value_parser = parse_xy, allow_hyphen_values = true)]
    pub(crate) at: Vec<[f64; 2]>,
    /// The vehicle (a TOML file, see `sil-host fly --help`); rotorpy's Crazyflie by default.
    #[arg(long, default_value = "vehicles/crazyflie-rotorpy.toml", value_name = "FILE")]
    pub(crate) vehicle: PathBuf,
    /// Hub distance from the centre of the Crazyflie's X, m.
    #[arg(long, default_value_t = 0.043, value_name = "M")]
    pub(crate) hub_m: f64,
    /// Controller: `pd`, `lqr` or `mpc` (the fast MPC at its 1 kHz preset).
    #[arg(long, value_parser = family_parser(), default_value = "mpc")]
    pub(crate) controller: Family,
    /// Form of the controller: `euler` or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    pub(crate) model: AttitudeForm,
    /// The estimator's position source: `mocap` (the SIL's motion capture: position and heading
    /// at 100 Hz) or `external` (only the client's `send_extpos` / `send_extpose`).
    #[arg(long, default_value = "mocap")]
    pub(crate) position_source: String,
    /// Send the plant's true pose (Crazyflie frame, JSON) to this UDP address every 10 ms: a
    /// motion-capture stream for clients and tests.
    #[arg(long, value_name = "HOST:PORT")]
    pub(crate) truth_to: Option<std::net::SocketAddr>,
    /// Stop after this long, s (default: run until killed).
    #[arg(long, value_name = "S")]
    pub(crate) duration: Option<f64>,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 1)]
    pub(crate) seed: u64,
    /// Where the vehicle runs: `in-process` (served on --listen), `qemu` (the `firmware-crtp`
    /// image: cflib reaches it through `tools/nrf51_bridge.py` on --syslink) or `qemu-crazyflie`
    /// (the Crazyflie 2.1 image, booted behind QEMU's stand-in for its bootloader, its motors on
    /// TIM2/TIM4).
    #[arg(long, default_value = "in-process", value_parser = ["in-process", "qemu", "qemu-crazyflie"])]
    pub(crate) target: String,
    /// With `--target qemu` or `qemu-crazyflie`: the TCP address of the image's USART6 (syslink), where
    /// `tools/nrf51_bridge.py --syslink` connects.
    #[arg(long, default_value = "127.0.0.1:19880", value_name = "HOST:PORT")]
    pub(crate) syslink: String,
    /// With `--target qemu` or `qemu-crazyflie`: how long the image waits for the bridge to connect, s.
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    pub(crate) bridge_wait: f64,
    /// Fault: every IMU sample in START,LENGTH (s of the plant's time) is NaN; the vehicle flies
    /// the last good one for 10 ms, then descends (its failsafe).
    #[arg(long, value_name = "START,LENGTH", value_parser = parse_window)]
    pub(crate) imu_dead: Option<(f64, f64)>,
    /// Fault: no motion-capture fix (nor its heading) in START,LENGTH (s of the plant's time); the
    /// estimator dead-reckons on the IMU.
    #[arg(long, value_name = "START,LENGTH", value_parser = parse_window)]
    pub(crate) fix_outage: Option<(f64, f64)>,
    /// Fault: the first motion-capture fix at or after S seconds (the plant's time) is 5 m off
    /// (north); the estimator's gate refuses it.
    #[arg(long, value_name = "S")]
    pub(crate) fix_outlier_at: Option<f64>,
    /// Keep persistent parameters in this file, as the vehicle's flash (made if missing; in
    /// process only): cflib's `param.persistent_store` writes the value in force there,
    /// `persistent_clear` forgets it, and the next start flies with what is stored.
    #[arg(long, value_name = "FILE")]
    pub(crate) storage: Option<PathBuf>,
}

#[derive(Args, Debug, Clone)]
pub(crate) struct Px4HilArgs {
    /// The simulator's address.
    #[arg(long, default_value = "127.0.0.1:4560", value_name = "HOST:PORT")]
    pub(crate) connect: String,
    /// Keep trying to connect for this long, s.
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    pub(crate) connect_timeout: f64,
    /// Controller: `pd`, `lqr` or `mpc`.
    #[arg(long, value_parser = family_parser(), default_value = "lqr")]
    pub(crate) controller: Family,
    /// Form of the controller: `euler` or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    pub(crate) model: AttitudeForm,
    /// The vehicle (a TOML file, see `sil-host fly --help`); e.g. vehicles/crazyflie-rotorpy.toml.
    #[arg(long, value_name = "FILE")]
    pub(crate) vehicle: PathBuf,
    /// Rotor layout and motor order (`MOT_FRAME`): `x-rotorpy`, `x-px4` (PX4's quad X), `x-betaflight`
    /// (Betaflight's Quad X, props in), `x-crazyflie` (the Crazyflie's M1–M4), all with hubs at --hub-m
    /// at 45°; or `plus` (the OS4's, at the vehicle's arm). The simulator's motors must be in that order.
    #[arg(long, default_value = "x-rotorpy")]
    pub(crate) airframe: String,
    /// Hub distance from the centre for `x-rotorpy`, m.
    #[arg(long, default_value_t = 0.043, value_name = "M")]
    pub(crate) hub_m: f64,
    /// Motor command unit: `speed` (fraction of the maximum rotor speed, as rotorpy reads it), `thrust` (fraction of the maximum thrust) or `pwm` (1000–2000 µs, linear in speed).
    #[arg(long, default_value = "speed")]
    pub(crate) motor_unit: String,
    /// Where the flight controller runs: `in-process`, or `qemu` (the `firmware-mavlink` image in
    /// QEMU's netduinoplus2, USART1 bridged to the simulator and the ground station; its
    /// parameters are written with PARAM_SET before the flight).
    #[arg(long, default_value = "in-process")]
    pub(crate) target: String,
    /// A ground station's UDP address (QGroundControl's is 127.0.0.1:14550): telemetry is sent
    /// there and its commands, set-points and parameter writes are obeyed.
    #[arg(long, value_name = "HOST:PORT")]
    pub(crate) gcs: Option<std::net::SocketAddr>,
    /// Fly only what the ground station (--gcs) commands: no mission of our own.
    #[arg(long, requires = "gcs", conflicts_with_all = ["waypoints", "scenario"])]
    pub(crate) gcs_only: bool,
    /// Mission: `T,N,E,D` (from T s, hold N, E, D m about home; heading: the one it has at take-off), repeatable, in time order.
    #[arg(long = "waypoint", value_name = "T,N,E,D", required_unless_present_any = ["scenario", "gcs_only", "trajectory"])]
    pub(crate) waypoints: Vec<String>,
    /// Or a scenario's trajectory (`circle`, `helix`, `setpoint`, `eight`; docs/book/src/model.md §9, starting 1 m
    /// above home), flown from --scenario-start s after holding its start point.
    #[arg(long, value_enum, conflicts_with = "waypoints")]
    pub(crate) scenario: Option<ScenarioKind>,
    /// When the scenario starts, s.
    #[arg(long, default_value_t = 3.0, value_name = "S")]
    pub(crate) scenario_start: f64,
    /// Or a Crazyflie trajectory file (one piece a row: duration, then the eight coefficients of
    /// x, y, z and yaw, the Crazyflie's frame; `uav_trajectories`' CSV), handed to the vehicle as if
    /// uploaded: it hovers 1 m above home heading north, then at --trajectory-start flies the
    /// trajectory on board from there (relative, as `autonomous_sequence_high_level.py` starts it),
    /// its controller previewing it. In process only.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["waypoints", "scenario", "gcs_only"])]
    pub(crate) trajectory: Option<PathBuf>,
    /// When the trajectory starts, s.
    #[arg(long, default_value_t = 5.0, value_name = "S")]
    pub(crate) trajectory_start: f64,
    /// The controller extrapolates each step's set-point instead of previewing what the commander
    /// flies: a measurement of what the preview is worth, not a flight mode (in process only).
    #[arg(long)]
    pub(crate) no_preview: bool,
    /// Stop after this much simulated time, s.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    pub(crate) duration: f64,
    /// Rate of the position fixes taken from HIL_STATE_QUATERNION, Hz.
    #[arg(long, default_value_t = 100.0, value_name = "HZ")]
    pub(crate) fix_hz: f64,
    /// Set a flight-controller parameter before the flight (`NAME=VALUE`, repeatable, after the
    /// options above; e.g. `PD_ROLL_P=250`, `MPC_W_U=4`; the book's MAVLink chapter lists them). Checked as the
    /// vehicle checks a PARAM_SET: a refused one is an error.
    #[arg(long = "param", value_name = "NAME=VALUE")]
    pub(crate) params: Vec<String>,
    /// Write the trace (t, reported NED, estimated NED, set-point NED) as CSV.
    #[arg(long, value_name = "PATH")]
    pub(crate) csv: Option<PathBuf>,
    /// Write the flight as a ULog (PX4's log format: pyulog, PlotJuggler, Flight Review), as it
    /// flies: the simulator's truth, the estimate, the set-point, the motors, arming, STATUSTEXTs
    /// and the parameters, under PX4's topic names.
    #[arg(long, value_name = "PATH")]
    pub(crate) ulog: Option<PathBuf>,
    /// Keep the vehicle's settings in this file, as its flash (made if missing; in process only):
    /// parameters a ground station sets and the MAVLink signing key are read at the next start
    /// (after --param, which gives the defaults), and the key's timestamp goes on from where it
    /// ended.
    #[arg(long, value_name = "FILE")]
    pub(crate) storage: Option<PathBuf>,
    /// What the controllers fly: `estimate` (the estimator's, from the simulated sensors: the
    /// whole flight controller) or `truth` (the simulator's true state, from its ODOMETRY
    /// messages, once the estimator has aligned: the controller alone, as a peer given perfect
    /// state flies; in process only, a measurement, not a flight mode).
    #[arg(long, default_value = "estimate", value_name = "SOURCE")]
    pub(crate) state: String,
}

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub(crate) struct SweepArgs {
    /// `merge`: put shards together (see `sweep merge --help`).
    #[command(subcommand)]
    pub(crate) action: Option<SweepAction>,
    /// Number of true vehicles drawn (each flown by all 8 controller variants).
    #[arg(long, default_value_t = 400, value_name = "N")]
    pub(crate) samples: usize,
    /// Seed of the generator: the same seed draws the same vehicles.
    #[arg(long, default_value_t = 1, value_name = "S")]
    pub(crate) seed: u64,
    /// Mass within ± this percentage of nominal.
    #[arg(long, default_value_t = 20.0, value_name = "PCT")]
    pub(crate) mass_pct: f64,
    /// Each principal inertia within ± this percentage.
    #[arg(long, default_value_t = 30.0, value_name = "PCT")]
    pub(crate) inertia_pct: f64,
    /// Every translational and rotational drag coefficient within ± this percentage.
    #[arg(long, default_value_t = 50.0, value_name = "PCT")]
    pub(crate) drag_pct: f64,
    /// Rotor lag time constant drawn in [0, this] s (0 turns the lag off).
    #[arg(long, default_value_t = 0.2, value_name = "S")]
    pub(crate) lag_max_s: f64,
    /// Rotor thrust coefficient within ± this percentage.
    #[arg(long, default_value_t = 10.0, value_name = "PCT")]
    pub(crate) kf_pct: f64,
    /// Steady horizontal wind up to this speed, m/s, from a random direction.
    #[arg(long, default_value_t = 3.0, value_name = "M_PER_S")]
    pub(crate) wind_max: f64,
    /// Sensor latency drawn in [0, this] ms.
    #[arg(long, default_value_t = 5.0, value_name = "MS")]
    pub(crate) latency_max_ms: f64,
    /// Fly only the slice I of N (samples with index ≡ I mod N) and write it
    /// as DIR/shard-I-of-N.jsonl; `sweep merge` puts the shards together.
    /// For job arrays: `--shard $SLURM_ARRAY_TASK_ID/$COUNT`.
    #[arg(long, value_name = "I/N", value_parser = parse_shard)]
    pub(crate) shard: Option<(usize, usize)>,
    /// A flight succeeds if it never strays farther than this from the reference, m.
    #[arg(long, default_value_t = 1.0, value_name = "M")]
    pub(crate) tube_m: f64,
    /// Scenario flown (docs/book/src/model.md §9 defaults).
    #[arg(long, value_enum, default_value = "helix")]
    pub(crate) scenario: ScenarioKind,
    /// Scenario from a TOML file instead (see `fly --help`).
    #[arg(long, value_name = "FILE")]
    pub(crate) scenario_file: Option<PathBuf>,
    /// Flight length, s.
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    pub(crate) duration: f64,
    /// Nominal vehicle from a TOML file (see `fly --help`); the draws perturb it.
    #[arg(long, value_name = "FILE")]
    pub(crate) vehicle: Option<PathBuf>,
    /// Output directory (created if missing).
    #[arg(long, default_value = "sweep", value_name = "DIR")]
    pub(crate) out: PathBuf,
    /// Hide the progress bar.
    #[arg(long)]
    pub(crate) no_progress: bool,
}

#[derive(Subcommand, Debug)]
pub(crate) enum SweepAction {
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
pub(crate) fn parse_shard(s: &str) -> Result<(usize, usize), String> {
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
pub(crate) struct ReportArgs {
    /// Output directory (created if missing).
    #[arg(long, default_value = "report", value_name = "DIR")]
    pub(crate) out: PathBuf,
    /// Reduced lengths for a fast look (under a minute on 2 cores): circle and helix 30 s, the
    /// horizon sweep 12 s, QEMU flights 0.5 s.
    #[arg(long)]
    pub(crate) quick: bool,
    /// Hide the progress bars.
    #[arg(long)]
    pub(crate) no_progress: bool,
    /// Do not fly the QEMU instructions-per-step table even if qemu-system-arm is installed
    /// (it is marked as skipped in the report).
    #[arg(long)]
    pub(crate) no_qemu: bool,
}

#[derive(Args, Debug)]
pub(crate) struct FlyArgs {
    /// Controller: `pd` (thesis gains, Tables 4.1-4.4), `lqr` (thesis weights, Tables 4.5/4.7)
    /// or `mpc` (linear MPC with the core's QP solver; see --preset).
    #[arg(long, value_parser = family_parser())]
    pub(crate) controller: Family,
    /// MPC preset: `fast` (50 ms prediction steps over 1 s, re-solved at 1 kHz) or `thesis`
    /// (Ts 0.25 s at 4 Hz, N 20, M 2, thesis weights). Other controllers ignore it.
    #[arg(long, value_parser = preset_parser(Family::Mpc), default_value = "fast")]
    pub(crate) preset: Preset,
    /// Form of the controller and of the plant: `euler` or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    pub(crate) model: AttitudeForm,
    /// Scenario (docs/book/src/model.md §9): `setpoint` (step to 3,2,-5 m and 15°), `circle` (R 2 m, 20 s), `helix` (circle climbing 0.05 m/s), `eight` (figure-8, A 1 m, 6 s lap, 20 s; RMSE from the end of the first lap).
    #[arg(long, value_enum, default_value = "setpoint")]
    pub(crate) scenario: ScenarioKind,
    /// Disturbances on the plant: none, wind, mismatch or wind,mismatch (docs/book/src/model.md §9).
    #[arg(long, default_value = "none", value_name = "SET")]
    pub(crate) disturbance: DisturbanceSet,
    /// Sensor noise on the state the controller sees: white, Gaussian, drawn every control step;
    /// SCALE × (5 mm, 2 cm/s, 0.3°, 0.6°/s) on position, velocity, attitude and body rates (1 σ).
    /// The metrics use the true state.
    #[arg(long, value_name = "SCALE")]
    pub(crate) noise: Option<f64>,
    /// Seed of the sensor noise (same seed, same noise), for --noise and for the simulated sensors.
    #[arg(long, default_value_t = 1, value_name = "N")]
    pub(crate) noise_seed: u64,
    /// What the controller flies on: `ekf` (simulated IMU and fixes through the on-board
    /// error-state Kalman filter) or `truth` (the true state, or --noise's version of it).
    /// Default: `ekf`, on every target (IMU and fix messages over the wire, protocol v5 and later); `truth`
    /// where ekf cannot run (controllers slower than 50 Hz, --noise), with a note.
    #[arg(long, value_enum, value_name = "EST")]
    pub(crate) estimator: Option<EstimatorArg>,
    /// Position source of `--estimator ekf`: `mocap` (100 Hz, 2 mm, 10 ms, with heading) or `gps`
    /// (10 Hz, 0.3/0.5 m, velocity, 100 ms; barometer and magnetometer). Default: mocap, or the
    /// scenario file's `[sensors]` table (profile, seed, IMU noise, faults), which these flags
    /// override (`--noise-seed` when not 1).
    #[arg(long, value_enum)]
    pub(crate) sensors: Option<FixProfile>,
    /// Fault: no position fix in START,LENGTH (s).
    #[arg(long, value_name = "START,LENGTH", value_parser = parse_window)]
    pub(crate) fix_outage: Option<(f64, f64)>,
    /// Fault: the first fix at or after S seconds is 5 m off.
    #[arg(long, value_name = "S")]
    pub(crate) fix_outlier_at: Option<f64>,
    /// Fault: the first IMU sample at or after S seconds is NaN.
    #[arg(long, value_name = "S")]
    pub(crate) imu_nan_at: Option<f64>,
    /// Fault: the IMU repeats one sample over START,LENGTH (s).
    #[arg(long, value_name = "START,LENGTH", value_parser = parse_window)]
    pub(crate) imu_stuck: Option<(f64, f64)>,
    /// Fault: a 30 g shock on body z at S seconds clips the accelerometer.
    #[arg(long, value_name = "S")]
    pub(crate) accel_clip_at: Option<f64>,
    /// Circle/helix radius, m (default 2).
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub(crate) radius: Option<f64>,
    /// Circle/helix period of one revolution, s (default 20).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    pub(crate) period: Option<f64>,
    /// Helix climb rate, m/s of altitude gained (default 0.05).
    #[arg(long, value_name = "M_PER_S", allow_hyphen_values = true)]
    pub(crate) climb_rate: Option<f64>,
    /// Either the set-point target X,Y,Z,YAW_DEG (NED m and heading in degrees; default 3,2,-5,15)
    /// or where the controller runs: `in-process` (default; called directly), `framed` (the
    /// flight-controller core in this process, reached only through the framed wire protocol) or
    /// `tcp:HOST:PORT` (a flight controller behind the protocol, e.g. `sil-host serve`) or `qemu`
    /// (the thumbv7em image in qemu-system-arm's netduinoplus2 over the emulated USART; the JSON
    /// then adds instructions per step; ≈ 4-9 ms of real time per step). Give it twice for both,
    /// e.g. `--target 1,2,-3,45 --target framed`.
    #[arg(long, value_name = "X,Y,Z,YAW_DEG|TARGET", value_parser = parse_target_arg, allow_hyphen_values = true)]
    pub(crate) target: Vec<TargetArg>,
    /// Flight length, s (default 20 for setpoint, 100 for circle and helix).
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    pub(crate) duration: Option<f64>,
    /// Reference handling: `feedforward` (reference velocity, and the attitude and thrust its
    /// acceleration implies) or `thesis` (reference position and velocity only, as the thesis).
    #[arg(long, value_parser = reference_parser(), default_value = "feedforward")]
    pub(crate) reference: ReferenceMode,
    /// PD gains: `tuned` (the thesis gains with the roll/pitch and quaternion z corrections
    /// explained in the book's controllers chapter) or `thesis` (Tables 4.1-4.4 as printed). LQR ignores it.
    #[arg(long, value_parser = preset_parser(Family::Pd), default_value = "tuned")]
    pub(crate) gains: Preset,
    /// Controller rate of PD and LQR, Hz [default: 500]. The MPC presets fix their own rate, so
    /// the MPC refuses it; the JSON's `control_hz` is the rate flown.
    #[arg(long, value_name = "HZ", allow_negative_numbers = true)]
    pub(crate) control_hz: Option<f64>,
    /// Plant RK4 rate, Hz (sub-steps within each control period).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ", allow_negative_numbers = true)]
    pub(crate) integration_hz: f64,
    /// Step the flight controller on a simulator's grid, as a simulator that steps at
    /// PERIOD_MS does (rotorpy: 2 ms), each interval PERIOD_MS ± up to JITTER_MS (uniform,
    /// seeded by SEED, default 1), on plant steps (raise --integration-hz for sub-millisecond
    /// grids); the controller runs on its own schedule on those steps and is told each
    /// interval. True-state flights only (--estimator truth).
    #[arg(long, value_name = "PERIOD_MS[,JITTER_MS[,SEED]]", value_parser = parse_step_grid)]
    pub(crate) step_grid: Option<sil_host::flight::StepGrid>,
    /// Vehicle parameters from a TOML file (any subset of mass_kg, gravity_mps2, inertia_kgm2,
    /// arm_m, rotor_inertia_kgm2, kf_ns2, km_nms2, kt_nspm, kr_nms, omega_max_radps, rotor_tau_s,
    /// rotor_gain; the rest stay OS4). Controllers are designed for it and the plant is it.
    #[arg(long, value_name = "FILE")]
    pub(crate) vehicle: Option<PathBuf>,
    /// Scenario from a TOML file (any subset of kind, start_ned_m, start_yaw_deg, target_ned_m,
    /// target_yaw_deg, radius_m, period_s, climb_rate_mps, duration_s; the rest are the docs/book/src/model.md §9
    /// defaults of its kind, --scenario when it names none). Other scenario options then apply
    /// on top of it.
    #[arg(long, value_name = "FILE")]
    pub(crate) scenario_file: Option<PathBuf>,
    /// Write the flight as CSV (one row per 10 ms, state columns then x_ref,y_ref,z_ref,psi_ref).
    #[arg(long, value_name = "PATH")]
    pub(crate) csv: Option<PathBuf>,
    /// Write the metrics as JSON (`-` for standard output).
    #[arg(long, value_name = "PATH")]
    pub(crate) json: Option<PathBuf>,
    /// Write the flight as a ULog (PX4's log format: pyulog, PlotJuggler, Flight Review), as it
    /// flies, every 10 ms: the plant's truth (PX4's ground-truth topics), the estimate, the
    /// reference, the motors and the flight's parameters, under PX4's topic names.
    #[arg(long, value_name = "PATH")]
    pub(crate) ulog: Option<PathBuf>,
    /// With `--target qemu`: print the firmware's own log (defmt over semihosting, decoded with
    /// the image's format table) to standard error after the flight.
    #[arg(long)]
    pub(crate) firmware_log: bool,
    /// Over a link (framed, tcp, qemu): send N parameter reads with every step, right after its
    /// sample, as a ground station flooding the flight controller would (at most 16); each step
    /// waits for their answers, checked, before the next. With `--target qemu --firmware-log`,
    /// the image's timing line shows what the flood cost its tasks.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub(crate) param_flood: u16,
}

#[derive(Args, Debug)]
pub(crate) struct ServeArgs {
    /// Address to listen on, HOST:PORT (e.g. 127.0.0.1:7000).
    #[arg(long, value_name = "HOST:PORT")]
    pub(crate) listen: String,
    /// End a session after this many seconds without a valid frame, or when
    /// the client has not read its replies for that long.
    #[arg(long, default_value_t = 10.0, value_name = "S", allow_negative_numbers = true)]
    pub(crate) idle_timeout: f64,
    /// End any session after this many seconds, however busy (one client
    /// cannot hold the only slot forever).
    #[arg(long, default_value_t = 7200.0, value_name = "S", allow_negative_numbers = true)]
    pub(crate) max_session: f64,
    /// Stop after this many client sessions (default: serve forever).
    #[arg(long, value_name = "N")]
    pub(crate) max_clients: Option<usize>,
}

#[derive(Args, Debug)]
pub(crate) struct MpcStepArgs {
    /// Form of the MPC and the plant.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    pub(crate) model: AttitudeForm,
    /// MPC preset: `fast` or `thesis`.
    #[arg(long, value_parser = preset_parser(Family::Mpc), default_value = "fast")]
    pub(crate) preset: Preset,
    /// Scenario flown up to --at.
    #[arg(long, value_enum, default_value = "setpoint")]
    pub(crate) scenario: ScenarioKind,
    /// Time of the step to explain, s (the last MPC step at or before it).
    #[arg(long, value_name = "T")]
    pub(crate) at: f64,
    /// Disturbances on the plant: none, wind, mismatch or wind,mismatch.
    #[arg(long, default_value = "none", value_name = "SET")]
    pub(crate) disturbance: DisturbanceSet,
    /// Print JSON (the only output format; accepted for clarity).
    #[arg(long)]
    pub(crate) json: bool,
}

#[derive(Args, Debug)]
pub(crate) struct DesignArgs {
    #[command(subcommand)]
    pub(crate) what: DesignWhat,
}

#[derive(Subcommand, Debug)]
pub(crate) enum DesignWhat {
    /// Continuous-time LQR about hover at a heading: prints {"A","B","Q","R","K"} (row-major) with U = Uss - K dX.
    Lqr(DesignLqrArgs),
}

#[derive(Args, Debug)]
pub(crate) struct DesignLqrArgs {
    /// Form: `euler` (12 states, weights Table 4.5) or `quaternion` (reduced 12 states, Q = I, R = I).
    #[arg(long, value_parser = form_parser())]
    pub(crate) model: AttitudeForm,
    /// Hover heading psi_T the model is linearised about, degrees.
    #[arg(long, default_value_t = 0.0, value_name = "DEG", allow_hyphen_values = true)]
    pub(crate) yaw_deg: f64,
    /// Print JSON (the only output format; accepted for clarity).
    #[arg(long)]
    pub(crate) json: bool,
    /// The LQR the flight controller flies instead: the project's weights,
    /// the inputs weighted for the vehicle, designed in discrete time at
    /// --period-s (prints A, B, Q, R, ts_s and the discrete K).
    #[arg(long)]
    pub(crate) flown: bool,
    /// With --flown: the vehicle from a TOML file (see `fly --help`); the OS4 if not given.
    #[arg(long, value_name = "FILE", requires = "flown")]
    pub(crate) vehicle: Option<PathBuf>,
    /// With --flown: the control period, s (the flight loop flies the LQR every 2 ms).
    #[arg(long, default_value_t = 0.002, value_name = "S", requires = "flown")]
    pub(crate) period_s: f64,
}

/// Options shared by every command that builds a plant.
#[derive(Args, Debug, Clone)]
pub(crate) struct PlantArgs {
    /// Equations the plant integrates: `euler` (ZYX angles, singular at 90° pitch) or `quaternion`.
    #[arg(long, value_parser = form_parser(), default_value = "quaternion")]
    pub(crate) model: AttitudeForm,
    /// RK4 integration rate of the plant, Hz (each control period is cut into sub-steps at this rate).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ", allow_negative_numbers = true)]
    pub(crate) integration_hz: f64,
    /// Turn on the first-order rotor lag (tau = 0.178 s, gain 0.936, docs/book/src/model.md §6).
    #[arg(long)]
    pub(crate) rotor_lag: bool,
    /// Disturbances acting on the plant: none, wind, mismatch or wind,mismatch (docs/book/src/model.md §9).
    #[arg(long, default_value = "none", value_name = "SET")]
    pub(crate) disturbance: DisturbanceSet,
}

impl PlantArgs {
    pub(crate) fn config(&self) -> Result<PlantConfig> {
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
pub(crate) struct OpenLoopArgs {
    #[command(flatten)]
    pub(crate) plant: PlantArgs,
    /// Constant commanded input U1,U2,U3,U4: thrust N, roll force N, pitch force N, yaw torque N·m.
    /// Goes through the mixer inverse and rotor clamping (realised inputs are in the CSV).
    #[arg(long, value_name = "U1,U2,U3,U4", value_parser = parse_list::<4>, allow_hyphen_values = true)]
    pub(crate) u: [f64; 4],
    /// Length of the flight, s.
    #[arg(long, default_value_t = 3.0, value_name = "SECONDS")]
    pub(crate) duration: f64,
    /// Start position X,Y,Z in NED metres (hovering at rest, level).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_list::<3>, allow_hyphen_values = true, default_value = "0,0,-1")]
    pub(crate) start: [f64; 3],
    /// Start heading, degrees.
    #[arg(long, default_value_t = 0.0, value_name = "DEG", allow_negative_numbers = true)]
    pub(crate) yaw_deg: f64,
    /// Output CSV, one row per 10 ms: t,x,y,z,vx,vy,vz,q0,q1,q2,q3,phi,theta,psi,p,q,r,u1,u2,u3,u4.
    /// Without it the last row is printed.
    #[arg(long, value_name = "PATH")]
    pub(crate) csv: Option<PathBuf>,
}

/// A `--target` value of `fly`: a set-point or an execution target.
#[derive(Debug, Clone)]
pub(crate) enum TargetArg {
    /// X, Y, Z (NED m), heading (deg).
    Setpoint([f64; 4]),
    /// Where the controller runs.
    Exec(Target),
}

pub(crate) fn parse_step_grid(s: &str) -> Result<sil_host::flight::StepGrid, String> {
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

pub(crate) fn parse_target_arg(s: &str) -> Result<TargetArg, String> {
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
pub(crate) fn named<T: Copy + Send + Sync + 'static>(
    pairs: Vec<(&'static str, T)>,
) -> impl TypedValueParser<Value = T> {
    let names: Vec<&'static str> = pairs.iter().map(|(n, _)| *n).collect();
    PossibleValuesParser::new(names).try_map(move |s: String| {
        pairs
            .iter()
            .find(|(n, _)| *n == s)
            .map(|(_, v)| *v)
            .ok_or_else(|| format!("unknown value '{s}'"))
    })
}

pub(crate) fn family_parser() -> impl TypedValueParser<Value = Family> {
    named(Family::ALL.iter().map(|f| (f.name(), *f)).collect())
}

pub(crate) fn form_parser() -> impl TypedValueParser<Value = AttitudeForm> {
    named(AttitudeForm::ALL.iter().map(|f| (f.name(), *f)).collect())
}

pub(crate) fn reference_parser() -> impl TypedValueParser<Value = ReferenceMode> {
    named(ReferenceMode::ALL.iter().map(|m| (m.name(), *m)).collect())
}

/// The presets of `family` by their own names (`tuned`/`thesis` gains for
/// PD, `fast`/`thesis` for the MPC), from the spec table.
pub(crate) fn preset_parser(family: Family) -> impl TypedValueParser<Value = Preset> {
    let mut pairs: Vec<(&'static str, Preset)> = Vec::new();
    for r in SPECS.iter().filter(|r| r.family == family) {
        if !pairs.iter().any(|(n, _)| *n == r.preset_name) {
            pairs.push((r.preset_name, r.preset));
        }
    }
    named(pairs)
}

pub(crate) fn parse_list<const N: usize>(s: &str) -> Result<[f64; N], String> {
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

/// What the controller flies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum EstimatorArg {
    /// Simulated sensors through the on-board estimator.
    Ekf,
    /// The true state.
    Truth,
}

pub(crate) fn parse_window(s: &str) -> Result<(f64, f64), String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("'{x}': {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [a, b] if a.is_finite() && b.is_finite() && a >= 0.0 && b > 0.0 => Ok((a, b)),
        _ => Err(format!("'{s}': need START,LENGTH in s with START ≥ 0 and LENGTH > 0")),
    }
}

/// `X,Y` in m, each finite.
pub(crate) fn parse_xy(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|x| x.trim().parse::<f64>().map_err(|e| format!("'{x}': {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y] if x.is_finite() && y.is_finite() => Ok([x, y]),
        _ => Err(format!("'{s}': need X,Y in m, both finite")),
    }
}
