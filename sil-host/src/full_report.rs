//! `sil-host report`: the whole study written to a directory — `index.md`,
//! the same page as a self-contained `index.html`, and `figures/*.svg|png`.

use crate::disturbance::DisturbanceSet;
use crate::figures::{self, Figure};
use crate::flight::{fly, fly_target, FlightConfig, Target};
use crate::noise::SensorNoise;
use crate::scenario::{Scenario, ScenarioKind};
use crate::study::{self, find, Outcome, Sel, VARIANTS};
use crate::study_plots::{self, HorizonPoint};
use anyhow::{Context, Result};
use fc_core::control::{Family, Preset};
use fc_core::AttitudeForm;
use rayon::prelude::*;
use std::fmt::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What `report` does.
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// Output directory.
    pub out: PathBuf,
    /// Reduced lengths (circle/helix 30 s, short QEMU flights).
    pub quick: bool,
    /// Show progress bars.
    pub progress: bool,
    /// Fly the QEMU instruction-count table when QEMU is present.
    pub qemu: bool,
}

/// What was written.
#[derive(Debug, Clone)]
pub struct Written {
    /// `DIR/index.md`.
    pub index_md: PathBuf,
    /// `DIR/index.html`.
    pub index_html: PathBuf,
    /// Every figure file (SVG and PNG).
    pub figures: Vec<PathBuf>,
    /// Flights of the study matrix.
    pub flights: usize,
    /// Wall-clock time, s.
    pub seconds: f64,
    /// The study's outcomes (for tests that compare them with single flights).
    pub outcomes: Vec<Outcome>,
}

/// One row of the QEMU table.
#[derive(Debug, Clone)]
pub struct QemuRow {
    /// Controller label.
    pub label: String,
    /// Instructions per step (mean, max).
    pub instructions: (f64, f64),
    /// RMSE x, y, z in QEMU and in-process, m.
    pub rmse: ([f64; 3], [f64; 3]),
    /// Steps flown.
    pub steps: usize,
    /// Times the firmware entered its failsafe (no valid sensor frame for
    /// 50 ms of simulated time).
    pub failsafe_entries: u32,
}

/// Is `qemu-system-arm` on the PATH?
pub fn qemu_available() -> bool {
    std::process::Command::new("qemu-system-arm")
        .arg("--version")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Every controller on a short set-point in QEMU and in-process.
fn qemu_table(quick: bool, progress: bool) -> Result<Vec<QemuRow>> {
    // Build the image once up front (the flights then find it current).
    crate::link::firmware_elf()?;
    let mut cases = Vec::new();
    for (fam, preset) in VARIANTS {
        for model in AttitudeForm::ALL {
            let mut sc = Scenario::default_for(ScenarioKind::Setpoint);
            sc.duration_s = match (fam, preset, quick) {
                (Family::Mpc, Preset::Thesis, _) => 10.0, // 4 Hz: 41 steps
                (_, _, true) => 0.5,
                (_, _, false) => 2.0,
            };
            let mut cfg = FlightConfig::new(fam, model, sc);
            cfg.spec.preset = preset;
            cases.push(cfg);
        }
    }
    let b = study::progress_bar(cases.len(), "QEMU flights", progress);
    let rows = cases
        .par_iter()
        .map(|cfg| {
            b.set_message(study::label(cfg));
            let pil = fly_target(cfg, &Target::Qemu).with_context(|| format!("QEMU: {}", study::label(cfg)))?;
            let local = fly(cfg)?;
            b.inc(1);
            let r =
                |res: &crate::flight::FlightResult| [res.metrics.x.rmse_m, res.metrics.y.rmse_m, res.metrics.z.rmse_m];
            Ok(QemuRow {
                label: study::label(cfg),
                instructions: pil.instructions_per_step.unwrap_or((0.0, 0.0)),
                rmse: (r(&pil), r(&local)),
                steps: pil.steps,
                failsafe_entries: pil.link_counters.map_or(0, |c| c.failsafe_entries),
            })
        })
        .collect::<Result<Vec<_>>>();
    b.finish_and_clear();
    rows
}

fn headline(all: &[Outcome]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| controller (quaternion) | set-point settling x / z s | overshoot x % | helix RMSE m, calm | \
         helix RMSE m, wind+mismatch | u_norm (set-point) | host µs/step |\n|---|---|---|---|---|---|---|"
    );
    let worst = |o: Option<&Outcome>| {
        o.map_or("—".to_string(), |o| {
            let m = &o.res.metrics;
            let w = m.x.rmse_m.max(m.y.rmse_m).max(m.z.rmse_m);
            if o.res.diverged || w > 10.0 {
                format!("unstable ({w:.0})")
            } else {
                format!("{w:.3}")
            }
        })
    };
    for (fam, preset) in VARIANTS {
        let sel = Sel::defaults(preset);
        let q = AttitudeForm::Quaternion;
        let sp = find(all, fam, q, ScenarioKind::Setpoint, DisturbanceSet::NONE, sel);
        let calm = find(all, fam, q, ScenarioKind::Helix, DisturbanceSet::NONE, sel);
        let both = DisturbanceSet {
            wind: true,
            mismatch: true,
        };
        let hard = find(all, fam, q, ScenarioKind::Helix, both, sel);
        let opt = |v: Option<f64>| v.map_or("—".into(), |v| format!("{v:.2}"));
        let _ = writeln!(
            s,
            "| {} | {} / {} | {} | {} | {} | {} | {} |",
            study::variant_title(fam, preset),
            opt(sp.and_then(|o| o.res.metrics.x.settling_s)),
            opt(sp.and_then(|o| o.res.metrics.z.settling_s)),
            opt(sp.and_then(|o| o.res.metrics.x.overshoot_pct)),
            worst(calm),
            worst(hard),
            sp.map_or("—".into(), |o| format!("{:.4}", o.res.metrics.u_norm)),
            sp.map_or("—".into(), |o| format!("{:.1}", o.res.step_time_ns.mean / 1000.0)),
        );
    }
    s
}

fn horizon_table(points: &[HorizonPoint]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| N | horizon s | settling x / y / z / ψ s | overshoot x / y / z / ψ % | u_norm | QP iterations mean / max (bound) |\n\
         |---|---|---|---|---|---|"
    );
    let opt = |v: Option<f64>| v.map_or("—".into(), |v| format!("{v:.2}"));
    for p in points {
        let st: Vec<String> = p.axes.iter().map(|a| opt(a.settling_s)).collect();
        let ov: Vec<String> = p.axes.iter().map(|a| opt(a.overshoot_pct)).collect();
        let _ = writeln!(
            s,
            "| {}{} | {:.2} | {} | {} | {:.4} | {:.1} / {} ({}) |",
            p.n,
            if p.settled { "" } else { " (does not settle)" },
            p.n as f64 * 0.25,
            st.join(" / "),
            ov.join(" / "),
            p.u_norm,
            p.qp.0,
            p.qp.1,
            p.qp.2
        );
    }
    s
}

/// Noise scales of the sensor-noise table (× `SensorNoise::typical`).
const NOISE_SCALES: [f64; 3] = [0.0, 1.0, 2.0];

/// The windy helix (quaternion) for every controller, and the fast MPC with
/// its disturbance estimate held, at each noise scale: rows of
/// (title, [(flight, scale)]).
fn noise_flights(quick: bool) -> Vec<(String, Vec<FlightConfig>)> {
    let mut sc = Scenario::default_for(ScenarioKind::Helix);
    if quick {
        sc.duration_s = 20.0;
    }
    let mut rows = Vec::new();
    let with_noise = |base: FlightConfig| -> Vec<FlightConfig> {
        NOISE_SCALES
            .iter()
            .map(|&k| FlightConfig {
                noise: (k > 0.0).then(|| SensorNoise::typical(k, 1).expect("a valid scale")),
                ..base
            })
            .collect()
    };
    for (fam, preset) in VARIANTS {
        let mut cfg = FlightConfig::new(fam, AttitudeForm::Quaternion, sc);
        cfg.spec.preset = preset;
        cfg.disturbance = DisturbanceSet {
            wind: true,
            mismatch: false,
        };
        rows.push((study::variant_title(fam, preset), with_noise(cfg)));
        if fam == Family::Mpc && preset == Preset::Project {
            let mut held = fc_core::control::MpcConfig::fast(fc_core::control::AttitudeForm::Quaternion);
            held.disturbance_trend_s = None;
            cfg.mpc_override = Some(held);
            rows.push(("MPC fast, disturbance held (no trend)".to_string(), with_noise(cfg)));
        }
    }
    rows
}

/// Flies [`noise_flights`]; returns each row's title and position RMSE (m) per scale.
fn noise_table(quick: bool, progress: bool) -> Result<Vec<(String, Vec<f64>)>> {
    let rows = noise_flights(quick);
    let cfgs: Vec<FlightConfig> = rows.iter().flat_map(|(_, c)| c.iter().copied()).collect();
    let out = study::run_all(&cfgs, progress)?;
    // run_all keeps the order: each row's flights are one chunk, a flight per scale.
    Ok(rows
        .into_iter()
        .zip(out.chunks(NOISE_SCALES.len()))
        .map(|((title, _), o)| (title, o.iter().map(|o| o.res.metrics.position_rmse_m()).collect()))
        .collect())
}

fn noise_markdown(rows: &[(String, Vec<f64>)], quick: bool) -> String {
    let mut s = String::new();
    let t = SensorNoise::typical(1.0, 1).expect("scale 1");
    let _ = writeln!(
        s,
        "\n## Sensor noise\n\nThe helix with `wind`{}, quaternion form, with the controllers seeing the state through white \
         Gaussian noise drawn every control step (`sil-host fly --noise SCALE`): scale 1 is {} mm, {} cm/s, {:.1}° and \
         {:.1}°/s (1 σ) on position, velocity, attitude and body rates. Position RMSE of the true state, m. White noise \
         at the control rate is harsher than a real estimator's output. The fast MPC's disturbance trend is the part \
         most exposed to noise (it differentiates an estimate); the row without it shows what it is worth.\n",
        if quick { " (20 s)" } else { "" },
        t.pos_m * 1e3,
        t.vel_mps * 1e2,
        t.att_rad.to_degrees(),
        t.rate_radps.to_degrees()
    );
    s.push_str("| controller |");
    for k in NOISE_SCALES {
        let _ = write!(s, " noise × {k} |");
    }
    s.push_str("\n|---|");
    s.push_str(&"---|".repeat(NOISE_SCALES.len()));
    s.push('\n');
    for (title, rmse) in rows {
        let _ = write!(s, "| {title} |");
        for r in rmse {
            let _ = write!(s, " {r:.4} |");
        }
        s.push('\n');
    }
    s
}

/// The figure-8 (`eight`, quaternion form) for every controller, calm and
/// in `wind`: `(title, [calm, wind])`.
fn eight_table(progress: bool) -> Result<Vec<(String, Vec<Outcome>)>> {
    let sc = Scenario::default_for(ScenarioKind::Eight);
    let winds = [
        DisturbanceSet::NONE,
        DisturbanceSet {
            wind: true,
            mismatch: false,
        },
    ];
    let mut cfgs = Vec::new();
    for (fam, preset) in VARIANTS {
        for d in winds {
            let mut cfg = FlightConfig::new(fam, AttitudeForm::Quaternion, sc);
            cfg.spec.preset = preset;
            cfg.disturbance = d;
            cfgs.push(cfg);
        }
    }
    let out = study::run_all(&cfgs, progress)?;
    Ok(VARIANTS
        .iter()
        .zip(out.chunks(winds.len()))
        .map(|(&(fam, preset), o)| (study::variant_title(fam, preset), o.to_vec()))
        .collect())
}

fn eight_markdown(rows: &[(String, Vec<Outcome>)]) -> String {
    let sc = Scenario::default_for(ScenarioKind::Eight);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\n## Figure-8 (`--scenario eight`)\n\nThe lemniscate of Gerono through the start point, A = {} m, a {} s lap \
         (peak {:.2} m/s and {:.2} m/s²), heading held, flown {} s from a hover at its start with its velocity, \
         acceleration and jerk as feed-forward; quaternion form, the study's vehicle. The error counts from the end \
         of the first lap ({} s): 3-D RMSE, worst and final distance from the reference, m; u_norm as in the \
         tables above.\n\n| controller | RMSE calm | worst calm | final calm | u_norm calm | RMSE wind | worst wind |\n\
         |---|---|---|---|---|---|---|",
        sc.radius_m,
        sc.period_s,
        (0..6000)
            .map(|i| sc.reference(f64::from(i) * sc.period_s / 6000.0).vel.norm())
            .fold(0.0, f64::max),
        sc.peak_horizontal_acceleration(),
        sc.duration_s,
        sc.tracking_from_s().unwrap_or(0.0)
    );
    for (title, o) in rows {
        let m = |k: usize| &o[k].res.metrics;
        let f = |v: Option<f64>, diverged: bool| match v {
            _ if diverged => "diverged".to_string(),
            Some(v) => format!("{v:.4}"),
            None => "—".to_string(),
        };
        let _ = writeln!(
            s,
            "| {title} | {} | {} | {:.4} | {:.4} | {} | {} |",
            f(m(0).tracking_rmse_m, o[0].res.diverged),
            f(m(0).tracking_worst_m, o[0].res.diverged),
            m(0).final_error_m,
            m(0).u_norm,
            f(m(1).tracking_rmse_m, o[1].res.diverged),
            f(m(1).tracking_worst_m, o[1].res.diverged),
        );
    }
    s
}

fn figure_markdown(f: &Figure) -> String {
    format!(
        "![{}](figures/{}.svg)\n\n[PNG](figures/{}.png) · [SVG](figures/{}.svg)\n\n",
        f.title, f.stem, f.stem, f.stem
    )
}

/// The book's chapters the report points its reader to: `(file under
/// docs/book/src, title, what it explains)`.
const BOOK_CHAPTERS: [(&str, &str, &str); 7] = [
    (
        "model.md",
        "The model",
        "the equations, the scenarios and metrics, and the thesis' corrections",
    ),
    (
        "controllers.md",
        "Controllers",
        "PD and LQR, feed-forward and integral action",
    ),
    (
        "mpc.md",
        "The MPC and its exact QP",
        "the presets, the solver, and the comparison with TinyMPC",
    ),
    (
        "estimator.md",
        "The estimator",
        "flying from sensors: the IMU, the fixes and the error-state Kalman filter",
    ),
    (
        "firmware.md",
        "The firmware image",
        "QEMU and the worst-case budgets behind the instruction counts",
    ),
    (
        "sweeps.md",
        "Robustness sweeps",
        "the sweep above, and running it on a cluster",
    ),
    (
        "simulation.md",
        "Simulation",
        "every flight option, to fly any row of this report yourself",
    ),
];

/// The "Read on" section: links from the report's directory `out` to the
/// book's chapter sources (Markdown, readable in place and rendered by
/// mdBook), relative so that they work wherever the repository is.
fn read_on(out: &Path) -> String {
    let book = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/book/src");
    let (out, book) = match (out.canonicalize(), book.canonicalize()) {
        (Ok(o), Ok(b)) => (o, b),
        // No book beside this binary (an installed sil-host): say where it is.
        _ => {
            return "\n## Read on\n\nThe book (`docs/book/` in the repository) explains every part of this report.\n"
                .into()
        }
    };
    let rel = pathdiff::diff_paths(&book, &out).unwrap_or(book);
    let mut s = String::from("\n## Read on\n\nThe book explains what this report measures:\n\n");
    for (file, title, what) in BOOK_CHAPTERS {
        let link = rel.join(file);
        let _ = writeln!(s, "- [{title}]({}): {what}", link.to_string_lossy().replace('\\', "/"));
    }
    s
}

/// The peer table (`docs/peers/index.md`: ours and rotorpy's SE3 on
/// rotorpy's vehicles, from rotorpy's truth), copied in as it was flown by
/// `tools/peer_table.py fly`: rotorpy is Python, so this command does not
/// fly it; the table says when and with which packages it was.
fn peers_markdown() -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/peers/index.md");
    let mut s = String::from("\n## Against the controllers users fly (rotorpy)\n\n");
    match std::fs::read_to_string(&path) {
        Ok(text) => {
            let flown = text.lines().find(|l| l.contains(" flown on ")).unwrap_or("");
            let _ = writeln!(
                s,
                "Our controllers, through their own estimator and on rotorpy's true state, beside rotorpy's \
                 SE3 geometric controller (true state), on rotorpy's Crazyflie and Hummingbird; every figure is \
                 rotorpy's true state against the reference. Not flown by this command: copied from \
                 `docs/peers/index.md`, which `python3 tools/peer_table.py fly docs/peers` writes{}.\n",
                flown
                    .split(" flown on ")
                    .nth(1)
                    .map(|f| format!(" (flown on {}", f.trim_end_matches('.')) + ")")
                    .unwrap_or_default()
            );
            let tables = text.find("\n**").map_or("", |i| &text[i + 1..]);
            s.push_str(tables);
        }
        Err(_) => s.push_str(
            "Not flown yet: `python3 tools/peer_table.py fly docs/peers` flies it (rotorpy, Python) and writes \
             `docs/peers/index.md`, which this report then copies.\n",
        ),
    }
    s
}

/// Flies the study and writes the report.
pub fn write_report(o: &ReportOptions) -> Result<Written> {
    let t0 = Instant::now();
    // Refuse an unusable destination before flying for seconds.
    crate::record::prepare_output_dir(&o.out)?;
    let cfgs = study::matrix(o.quick);
    let all = study::run_all(&cfgs, o.progress)?;
    let horizon = study_plots::horizon_sweep(AttitudeForm::Quaternion, o.quick)?;
    // The robustness sweep at the `sweep` command's defaults (400 vehicles;
    // 8 with --quick).
    let sweep_opts = crate::sweep::SweepOptions {
        samples: if o.quick { 8 } else { 400 },
        progress: o.progress,
        ..crate::sweep::SweepOptions::defaults(
            {
                let mut b = Scenario::default_for(ScenarioKind::Helix);
                b.duration_s = 30.0;
                b
            },
            o.out.join("sweep"),
        )
    };
    let sweep_rows = crate::sweep::run(&sweep_opts)?;
    crate::sweep::write(&sweep_opts, &sweep_rows)?;
    let noise = noise_table(o.quick, o.progress)?;
    let eight = eight_table(o.progress)?;
    let sensed = crate::estimation_report::run(o.quick, o.progress)?;
    let qemu = if !o.qemu {
        Err("not requested (--no-qemu)".to_string())
    } else if !qemu_available() {
        Err("skipped: qemu-system-arm not found (Debian package qemu-system-arm; ./test.sh installs it)".to_string())
    } else {
        qemu_table(o.quick, o.progress).map_err(|e| format!("skipped: {e:#}"))
    };

    let fig_dir = o.out.join("figures");
    std::fs::create_dir_all(&fig_dir).with_context(|| format!("creating {}", fig_dir.display()))?;
    let mut figs = study_plots::study_figures(&all);
    figs.push(study_plots::horizon_figure(&horizon));
    let est_figs = crate::estimation_report::figures(&sensed);
    figs.extend(est_figs.iter().cloned());
    let b = study::progress_bar(figs.len(), "figures", o.progress);
    figs.par_iter()
        .map(|f| {
            b.set_message(f.stem.clone());
            let r = figures::write(&fig_dir, f).with_context(|| format!("figure {}", f.stem));
            b.inc(1);
            r
        })
        .collect::<Result<Vec<_>>>()?;
    b.finish_and_clear();

    let elapsed = t0.elapsed().as_secs_f64();
    let mut md = String::new();
    md.push_str("# The thesis' study, redone by the firmware core\n\n");
    let _ = writeln!(
        md,
        "Generated by `sil-host report{}`: {} flights of the f32 core (PD and LQR at 500 Hz, MPC at its preset's \
         rate) against the f64 plant at 1 kHz, {} horizon-sweep flights, {} sensor-noise flights, {} flights from simulated \
         sensors, {} figure-8 flights and {} QEMU flights, in {:.1} s on {} threads. Regenerate rather than edit. Figures are SVG (PNG beside them).\n",
        if o.quick { " --quick" } else { "" },
        all.len(),
        horizon.len(),
        noise.len() * NOISE_SCALES.len(),
        sensed.len(),
        eight.len() * 2,
        qemu.as_ref().map_or(0, |r| r.len()),
        elapsed,
        rayon::current_num_threads()
    );
    md.push_str("## Headline\n\n");
    md.push_str(&headline(&all));
    md.push_str(
        "\nSettling: 2 % band of the step. Helix RMSE: the worst axis. PD, LQR and the fast MPC hold their tracking \
         under wind and a 15 % heavier vehicle with rotor lag (disturbance observers: the MPC's, and the PD's and \
         LQR's integral action); the thesis preset, re-planning at 4 Hz, cannot hold the 0.178 s rotor lag of \
         `mismatch` (see the explanations).\n\n",
    );
    md.push_str("## Figures\n\n");
    for f in figs.iter().filter(|f| !f.stem.starts_with("estimate_")) {
        md.push_str(&figure_markdown(f));
    }
    md.push_str(&study::tables_markdown(&all));
    md.push_str("\n## Prediction horizon (thesis Figs 4.9–4.10, swept)\n\n");
    md.push_str(
        "The `thesis` preset (Ts 0.25 s, M 2, Appendix C weights, 4 Hz) on the set-point, quaternion form, with the \
         prediction horizon N varied. The thesis showed a few horizons; here every N is flown by the same core \
         (the horizon is a const generic, so each N is its own monomorphised controller).\n\n",
    );
    md.push_str(&horizon_table(&horizon));
    let _ = writeln!(
        md,
        "\n## Robustness (Monte Carlo)\n\n{} true vehicles (seed 1, the `sweep` command's default ranges): {}; \
         the helix for 30 s; success = no divergence and never more than 1 m from the reference. The project's \
         controllers (PD, LQR, MPC fast) are the product; the thesis MPC is flown beside them for comparison. \
         `sil-host sweep --samples N --seed S` runs other sweeps (every range is a flag). \
         [Details and every flight](sweep/sweep.md).\n",
        sweep_opts.samples,
        crate::sweep::describe_ranges(&sweep_opts)
    );
    let _ = writeln!(
        md,
        "| controller | success % | RMSE p50 m | RMSE p90 m | RMSE max m |\n|---|---|---|---|---|"
    );
    for r in &sweep_rows {
        let p = r.rmse_percentiles_m;
        let _ = writeln!(
            md,
            "| {} | {:.1} | {:.3} | {:.3} | {:.3} |",
            r.controller, r.success_pct, p[0], p[1], p[3]
        );
    }
    md.push_str(
        "\n![Robustness: RMSE distribution per controller](sweep/sweep_rmse.svg)\n\n[PNG](sweep/sweep_rmse.png)\n",
    );
    md.push_str(&eight_markdown(&eight));
    md.push_str(&noise_markdown(&noise, o.quick));
    md.push_str(&crate::estimation_report::markdown(&sensed));
    md.push('\n');
    for f in &est_figs {
        md.push_str(&figure_markdown(f));
    }
    md.push_str("\n## Instructions per step on the STM32F405 (QEMU)\n\n");
    match &qemu {
        Ok(rows) => {
            md.push_str(
                "The thumbv7em image in QEMU's netduinoplus2 (`-icount shift=0`: SysTick counts 0.168 per executed \
                 instruction), flown in lockstep over the emulated USART on a short set-point, beside the same \
                 flight in-process. Worst-case budgets: the book's firmware chapter, `firmware/stm32f405/src/bin/budget/main.rs`. The \
                 firmware's failsafe timer runs on the frames' simulated time, so a busy host cannot trigger it: \
                 the failsafe column is 0 unless the flight itself starves the controller of valid frames.\n\n\
                 | controller | steps | instructions mean | instructions max | RMSE x/y/z m, QEMU | RMSE x/y/z m, in-process | failsafe entries |\n\
                 |---|---|---|---|---|---|---|\n",
            );
            for r in rows {
                let f = |v: [f64; 3]| format!("{:.4} / {:.4} / {:.4}", v[0], v[1], v[2]);
                let _ = writeln!(
                    md,
                    "| {} | {} | {:.0} | {:.0} | {} | {} | {} |",
                    r.label,
                    r.steps,
                    r.instructions.0,
                    r.instructions.1,
                    f(r.rmse.0),
                    f(r.rmse.1),
                    r.failsafe_entries
                );
            }
        }
        Err(why) => {
            let _ = writeln!(md, "{why}.");
        }
    }
    md.push_str(&peers_markdown());
    md.push('\n');
    md.push_str(study::EXPLANATIONS);
    std::fs::create_dir_all(&o.out).with_context(|| format!("creating {}", o.out.display()))?;
    md.push_str(&read_on(&o.out));

    let index_md = o.out.join("index.md");
    std::fs::write(&index_md, &md).with_context(|| format!("writing {}", index_md.display()))?;
    let html = crate::html::markdown_to_html(&md, "The thesis' study, redone by the firmware core", &o.out);
    let index_html = o.out.join("index.html");
    std::fs::write(&index_html, html).with_context(|| format!("writing {}", index_html.display()))?;
    let mut figures: Vec<PathBuf> = figs
        .iter()
        .flat_map(|f| ["svg", "png"].map(|e| fig_dir.join(format!("{}.{e}", f.stem))))
        .collect();
    figures.extend(["svg", "png"].map(|e| o.out.join(format!("sweep/sweep_rmse.{e}"))));
    Ok(Written {
        index_md,
        index_html,
        figures,
        flights: all.len(),
        seconds: t0.elapsed().as_secs_f64(),
        outcomes: all,
    })
}

/// Every relative link target (`](target)`) in a Markdown file that does not
/// exist on disk.
pub fn missing_links(index_md: &Path) -> Result<Vec<String>> {
    let md = std::fs::read_to_string(index_md)?;
    let dir = index_md.parent().unwrap_or(Path::new("."));
    let mut missing = Vec::new();
    for part in md.split("](").skip(1) {
        let Some(end) = part.find(')') else { continue };
        let target = &part[..end];
        if target.contains("://") || target.starts_with('#') {
            continue;
        }
        if !dir.join(target).exists() {
            missing.push(target.to_string());
        }
    }
    Ok(missing)
}
