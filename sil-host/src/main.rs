//! `sil-host`: fly the flight-control core against the nonlinear plant.
//!
//! Subcommands: `open-loop` (constant inputs from hover). Closed-loop
//! flights (`fly`), controller design (`design`), MPC step inspection
//! (`mpc-step`), the framed-link server (`serve`) and the study (`report`,
//! `sweep`) build on the same plant, scenarios and metrics.

use anyhow::{bail, Context, Result};
use clap::Parser;
use fc_core::control::{Family, Preset};
use sil_host::flight::Recording;
use sil_host::flight::{FlightConfig, Target};
use sil_host::flight_log::{FlyULog, Tee};
use sil_host::openloop::OpenLoop;
use sil_host::record::{CsvSink, Discard, STATE_COLUMNS};
use sil_host::scenario::Scenario;
use sil_host::sensors::{FixProfile, SensorConfig};
use std::io::IsTerminal;
use std::path::PathBuf;

mod cli;

use cli::*;

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
    let starts_m = if a.at.is_empty() {
        sil_host::crtp::grid_starts(a.count)
    } else if a.at.len() == a.count {
        a.at.clone()
    } else {
        bail!(
            "--count {} needs as many --at (one start per vehicle), not {}",
            a.count,
            a.at.len()
        );
    };
    // SIGINT/SIGTERM end the flight at the next step: the summary is written
    // and QEMU (with --target qemu) stopped, not left orphaned.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
        .context("installing the SIGINT/SIGTERM handler")?;
    let summary = sil_host::crtp::run(&sil_host::crtp::CrtpConfig {
        stop,
        listen: a.listen,
        starts_m,
        decks: a.deck.iter().fold(0u8, |m, d| {
            let bit = fc_crtp::vehicle::DECK_NAMES.iter().position(|n| n == d).unwrap_or(0);
            m | 1 << bit
        }),
        settings,
        vehicle,
        position_source,
        truth_to: a.truth_to,
        duration_s: a.duration,
        seed: a.seed,
        imu_dead: a.imu_dead,
        fix_outage: a.fix_outage,
        fix_outlier_at_s: a.fix_outlier_at,
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
        _ if a.trajectory.is_some() => {
            if !(a.trajectory_start.is_finite() && (1.0..=1e5).contains(&a.trajectory_start)) {
                bail!("--trajectory-start {:?} must be in [1, 1e5] s", a.trajectory_start);
            }
            if a.target != "in-process" {
                bail!("--trajectory is handed to the vehicle in this process: the image speaks no trajectory upload");
            }
            let path = a.trajectory.as_deref().unwrap_or(std::path::Path::new(""));
            let (memory, duration_s) = sil_host::hil::trajectory::load(path)?;
            let flown = sil_host::hil::trajectory::Flown::new(memory, duration_s, a.trajectory_start, [0.0, 0.0, -1.0])
                .with_context(|| format!("--trajectory {}", path.display()))?;
            Some(sil_host::hil::Mission::Trajectory(flown))
        }
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
        exact_preview: !a.no_preview,
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
