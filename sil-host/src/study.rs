//! The thesis' study redone by the firmware core: the flight matrix, run in
//! parallel, and its tables in the thesis' form beside the thesis' numbers.

use crate::disturbance::DisturbanceSet;
use crate::flight::{fly, FlightConfig, FlightResult};
use crate::metrics::AxisMetrics;
use crate::scenario::{Scenario, ScenarioKind};
use fc_core::control::{ControllerSpec, Family, Preset, ReferenceMode};
use fc_core::AttitudeForm;
use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;
use std::fmt::Write;

/// One flown case of the study.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// What was flown.
    pub cfg: FlightConfig,
    /// How it went.
    pub res: FlightResult,
}

/// Controller families of the study, in table order.
pub const FAMILIES: [Family; 3] = Family::ALL;
/// The controllers as the tables list them: family and MPC preset.
pub const VARIANTS: [(Family, Preset); 4] = [
    (Family::Pd, Preset::Project),
    (Family::Lqr, Preset::Project),
    (Family::Mpc, Preset::Project),
    (Family::Mpc, Preset::Thesis),
];
/// Models, in table order.
pub const MODELS: [AttitudeForm; 2] = AttitudeForm::ALL;
/// Scenarios, in table order.
pub const SCENARIOS: [ScenarioKind; 3] = [ScenarioKind::Setpoint, ScenarioKind::Circle, ScenarioKind::Helix];

/// The flight matrix: every controller × model × scenario × disturbance with
/// the project's defaults, plus the PD with the printed thesis gains on the
/// set-point. `quick` shortens circle and helix to 30 s.
pub fn matrix(quick: bool) -> Vec<FlightConfig> {
    let mut out = Vec::new();
    for (fam, preset) in VARIANTS {
        for model in MODELS {
            for kind in SCENARIOS {
                for d in DisturbanceSet::ALL {
                    let mut sc = Scenario::default_for(kind);
                    if quick && kind != ScenarioKind::Setpoint {
                        sc.duration_s = 30.0;
                    }
                    let mut cfg = FlightConfig::new(fam, model, sc);
                    cfg.disturbance = d;
                    cfg.spec.preset = preset;
                    out.push(cfg);
                }
            }
        }
    }
    for model in MODELS {
        let mut cfg = FlightConfig::new(Family::Pd, model, Scenario::default_for(ScenarioKind::Setpoint));
        cfg.spec.preset = Preset::Thesis;
        out.push(cfg);
    }
    // The thesis-faithful reference (no acceleration/rate feed-forward) on the tracking cases.
    for fam in [Family::Pd, Family::Lqr] {
        for model in MODELS {
            for kind in [ScenarioKind::Circle, ScenarioKind::Helix] {
                let mut sc = Scenario::default_for(kind);
                if quick {
                    sc.duration_s = 30.0;
                }
                let mut cfg = FlightConfig::new(fam, model, sc);
                cfg.spec.reference = ReferenceMode::Thesis;
                out.push(cfg);
            }
        }
    }
    out
}

/// A short label for progress, errors and the QEMU table: family (and MPC
/// preset), form, scenario, disturbance, and the non-default choices.
pub fn label(cfg: &FlightConfig) -> String {
    let spec = cfg.spec;
    let mut s = spec.family.name().to_string();
    if spec.family == Family::Mpc {
        s += &format!(" {}", spec.row().preset_name);
    }
    s += &format!(
        " {} {} [{}]",
        spec.form.name(),
        cfg.scenario.kind.name(),
        cfg.disturbance
    );
    if spec.family == Family::Pd && spec.preset == Preset::Thesis {
        s += " thesis gains";
    }
    if spec.reference == ReferenceMode::Thesis {
        s += " thesis reference";
    }
    s
}

/// A progress bar over `len` items of `what` that shows the current item
/// (hidden when `show` is false).
pub fn progress_bar(len: usize, what: &str, show: bool) -> ProgressBar {
    let b = if show {
        ProgressBar::new(len as u64)
    } else {
        ProgressBar::hidden()
    };
    b.set_style(
        ProgressStyle::with_template(&format!(
            "{{elapsed_precise}} [{{bar:30}}] {{pos}}/{{len}} {what}  {{wide_msg}}"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    b
}

/// Flies every case on all cores, with a progress bar when `progress`.
pub fn run_all(cfgs: &[FlightConfig], progress: bool) -> anyhow::Result<Vec<Outcome>> {
    let bar = progress_bar(cfgs.len(), "flights", progress);
    let out: anyhow::Result<Vec<Outcome>> = cfgs
        .par_iter()
        .map(|cfg| {
            bar.set_message(label(cfg));
            let res = fly(cfg).map_err(|e| e.context(label(cfg)))?;
            bar.inc(1);
            Ok(Outcome { cfg: *cfg, res })
        })
        .collect();
    bar.finish_and_clear();
    out
}

/// How a case was flown beyond controller, model, scenario and disturbance.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sel {
    /// Gain set or MPC preset.
    pub preset: Preset,
    /// Reference handling.
    pub reference: ReferenceMode,
}

impl Sel {
    /// A preset with the reference fed forward.
    pub fn defaults(preset: Preset) -> Self {
        Self {
            preset,
            reference: ReferenceMode::Feedforward,
        }
    }
}

/// Finds the outcome of a case.
pub fn find(
    all: &[Outcome],
    fam: Family,
    model: AttitudeForm,
    kind: ScenarioKind,
    d: DisturbanceSet,
    sel: Sel,
) -> Option<&Outcome> {
    let want = ControllerSpec::new(fam, model)
        .with_preset(sel.preset)
        .with_reference(sel.reference);
    all.iter()
        .find(|o| o.cfg.spec == want && o.cfg.scenario.kind == kind && o.cfg.disturbance == d)
}

/// Thesis set-point numbers: per axis x, y, z, ψ (q3 for the
/// quaternion form): (settling s, overshoot %).
pub fn thesis_setpoint(fam: Family, model: AttitudeForm) -> [(f64, f64); 4] {
    match (fam, model) {
        (Family::Pd, AttitudeForm::Euler) => [(4.09, 0.0), (3.07, 0.004), (1.77, 0.07), (1.15, 2.98)],
        (Family::Lqr, AttitudeForm::Euler) => [(2.16, 0.0), (1.83, 0.0), (1.85, 0.0), (0.60, 3.04)],
        (Family::Pd, AttitudeForm::Quaternion) => [(2.59, 1.74), (2.66, 13.12), (2.32, 2.79), (1.45, 4.25)],
        (Family::Lqr, AttitudeForm::Quaternion) => [(4.63, 0.0), (3.99, 0.0), (4.09, 0.0), (3.54, 0.006)],
        (Family::Mpc, AttitudeForm::Euler) => [(6.93, 2.26), (8.47, 2.77), (2.82, 0.02), (0.56, 1.21)],
        (Family::Mpc, AttitudeForm::Quaternion) => [(4.45, 1.64), (8.12, 3.98), (4.91, 2.23), (1.90, 0.25)],
    }
}

/// Thesis tracking RMSE % (x, y, z) (thesis chapter 4); `disturbed` selects the
/// thesis' disturbed tables (4.15–4.18).
pub fn thesis_rmse_pct(fam: Family, model: AttitudeForm, kind: ScenarioKind, disturbed: bool) -> Option<[f64; 3]> {
    use AttitudeForm::*;
    use Family::*;
    use ScenarioKind::*;
    Some(match (model, kind, disturbed, fam) {
        (Euler, Helix, false, Pd) => [0.93, 0.52, 0.50],
        (Euler, Helix, false, Lqr) => [0.95, 0.49, 0.43],
        (Quaternion, Helix, false, Pd) => [0.54, 0.86, 1.05],
        (Quaternion, Helix, false, Lqr) => [0.84, 2.55, 2.32],
        (Euler, Circle, false, Pd) => [0.82, 1.49, 0.10],
        (Euler, Circle, false, Lqr) => [1.71, 1.20, 0.31],
        (Quaternion, Circle, false, Pd) => [0.60, 0.88, 0.36],
        (Quaternion, Circle, false, Lqr) => [0.97, 2.44, 1.09],
        (Euler, Helix, true, Pd) => [0.97, 0.48, 0.52],
        (Euler, Helix, true, Lqr) => [3.25, 1.72, 0.13],
        (Euler, Circle, true, Pd) => [2.97, 2.00, 9.04],
        (Euler, Circle, true, Lqr) => [5.54, 0.86, 0.23],
        (Quaternion, Helix, true, Pd) => [1.18, 0.81, 0.24],
        (Quaternion, Helix, true, Lqr) => [48.9, 38.3, 2.66],
        (Quaternion, Circle, true, Pd) => [1.20, 0.91, 5.73],
        (Quaternion, Circle, true, Lqr) => [48.8, 38.5, 19.4],
        (Euler, Helix, false, Mpc) => [1.74, 1.97, 1.35],
        (Quaternion, Helix, false, Mpc) => [0.84, 3.90, 2.94],
        (Euler, Circle, false, Mpc) => [1.28, 6.27, 1.00],
        (Quaternion, Circle, false, Mpc) => [2.81, 3.84, 2.31],
        (Euler, Helix, true, Mpc) => [1.74, 1.97, 1.35],
        (Euler, Circle, true, Mpc) => [1.82, 6.86, 2.01],
        (Quaternion, Helix, true, Mpc) => [0.85, 3.91, 2.94],
        (Quaternion, Circle, true, Mpc) => [1.03, 2.97, 1.30],
        _ => return None,
    })
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    match v {
        Some(x) if x.is_finite() => format!("{x:.digits$}"),
        _ => "—".into(),
    }
}

fn axes(m: &crate::metrics::FlightMetrics) -> [AxisMetrics; 4] {
    [m.x, m.y, m.z, m.yaw]
}

/// How tables, figures and sweeps name a controller: `PD`, `LQR`, `MPC fast`, `MPC thesis`.
/// (The spec table's titles: the gain set is not part of the name.)
pub fn variant_title(f: Family, preset: Preset) -> String {
    ControllerSpec::new(f, AttitudeForm::Euler)
        .with_preset(preset)
        .title()
        .to_string()
}

fn model_title(m: AttitudeForm) -> &'static str {
    m.title()
}

/// Markdown tables of the study (PD and LQR).
pub fn tables_markdown(all: &[Outcome]) -> String {
    let mut s = String::new();
    let none = DisturbanceSet::NONE;
    let _ = writeln!(s, "## Set-point step (thesis Tables 4.1, 4.3, 4.6, 4.8)\n");
    let _ = writeln!(
        s,
        "Step from hover at (0, 0, −1) m, ψ 0° to (3, 2, −5) m, ψ 15°; 20 s; no disturbance. \
         Each cell: **ours** (thesis). Settling: 2 % band of the step; overshoot: % of the step. \
         The thesis' quaternion rows are for q3; ours are for ψ (the same rotation)."
    );
    let mut better = 0;
    let mut cells = 0;
    for (fam, preset) in VARIANTS {
        for model in MODELS {
            let mut rows = vec![(preset, "")];
            if fam == Family::Pd {
                rows.push((Preset::Thesis, ", printed thesis gains"));
            }
            for (gains, note) in rows {
                let Some(o) = find(all, fam, model, ScenarioKind::Setpoint, none, Sel::defaults(gains)) else {
                    continue;
                };
                let th = thesis_setpoint(fam, model);
                let _ = writeln!(
                    s,
                    "\n**{} {}{}** — final error {:.3} m, u_norm {:.4}, controller {:.0} ns/step\n",
                    variant_title(fam, preset),
                    model_title(model),
                    note,
                    o.res.metrics.final_error_m,
                    o.res.metrics.u_norm,
                    o.res.step_time_ns.mean
                );
                let _ = writeln!(s, "| axis | target | settling s | overshoot % |\n|---|---|---|---|");
                let targets = ["3 m", "2 m", "−5 m", "15°"];
                for (i, a) in axes(&o.res.metrics).iter().enumerate() {
                    let _ = writeln!(
                        s,
                        "| {} | {} | **{}** ({:.2}) | **{}** ({:.3}) |",
                        ["x", "y", "z", "ψ"][i],
                        targets[i],
                        fmt_opt(a.settling_s, 2),
                        th[i].0,
                        fmt_opt(a.overshoot_pct, 3),
                        th[i].1
                    );
                    // The variant's own gains only, not the printed-gains extra row.
                    if gains == preset {
                        cells += 1;
                        if a.settling_s.is_some_and(|v| v <= th[i].0) {
                            better += 1;
                        }
                    }
                }
            }
        }
    }
    let _ = writeln!(
        s,
        "\nVerdict: with the project's defaults every variant settles on every axis; ours settles no later than \
         the thesis in {better} of {cells} axis cells.\n"
    );

    for (title, dist, thesis_disturbed, reference) in [
        (
            "Tracking RMSE, undisturbed (thesis Tables 4.11–4.14)",
            none,
            false,
            ReferenceMode::Feedforward,
        ),
        (
            "Tracking RMSE, undisturbed, thesis-faithful reference (position and velocity only)",
            none,
            false,
            ReferenceMode::Thesis,
        ),
        (
            "Tracking RMSE with `wind` (thesis Tables 4.15–4.18, disturbed)",
            DisturbanceSet {
                wind: true,
                mismatch: false,
            },
            true,
            ReferenceMode::Feedforward,
        ),
        (
            "Tracking RMSE with `mismatch`",
            DisturbanceSet {
                wind: false,
                mismatch: true,
            },
            false,
            ReferenceMode::Feedforward,
        ),
        (
            "Tracking RMSE with `wind,mismatch`",
            DisturbanceSet {
                wind: true,
                mismatch: true,
            },
            false,
            ReferenceMode::Feedforward,
        ),
    ] {
        let _ = writeln!(s, "## {title}\n");
        let _ =
            writeln!(
            s,
            "RMSE as % of the reference's range per axis (4 m on x and y; z: 5 m on the helix, 1 m where constant). \
             Each cell: **ours** ({}); metres in the last column.\n",
            if dist == none || thesis_disturbed { "thesis" } else { "no thesis number" }
        );
        let _ = writeln!(
            s,
            "| case | PD x | PD y | PD z | LQR x | LQR y | LQR z | MPC fast x | MPC fast y | MPC fast z | \
             MPC thesis x | MPC thesis y | MPC thesis z | worst axis, m |\n\
             |---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
        );
        let mut wins = 0;
        let mut n = 0;
        for model in MODELS {
            for kind in [ScenarioKind::Helix, ScenarioKind::Circle] {
                let mut line = format!("| {} {} |", model_title(model), kind.name());
                let mut worst = 0.0f64;
                for (fam, preset) in VARIANTS {
                    let Some(o) = find(all, fam, model, kind, dist, Sel { preset, reference }) else {
                        continue;
                    };
                    let m = &o.res.metrics;
                    let th = if dist == none || thesis_disturbed {
                        thesis_rmse_pct(fam, model, kind, thesis_disturbed)
                    } else {
                        None
                    };
                    for (i, a) in [m.x, m.y, m.z].iter().enumerate() {
                        worst = worst.max(a.rmse_m);
                        let t = th.map(|t| t[i]);
                        let _ = write!(line, " **{:.2}** ({}) |", a.rmse_pct, fmt_opt(t, 2));
                        if let Some(t) = t {
                            n += 1;
                            if a.rmse_pct <= t {
                                wins += 1;
                            }
                        }
                    }
                }
                let _ = writeln!(s, "{line} {worst:.3} |");
            }
        }
        if n > 0 {
            let _ = writeln!(s, "\nVerdict: ours is at or below the thesis in {wins} of {n} cells.\n");
        } else {
            let _ = writeln!(s);
        }
    }

    let _ = writeln!(s, "## Set-point under disturbance\n");
    let _ = writeln!(s, "| controller | model | disturbance | final error m | z RMSE m | settling x/y/z/ψ s |\n|---|---|---|---|---|---|");
    for (fam, preset) in VARIANTS {
        for model in MODELS {
            for d in DisturbanceSet::ALL {
                let Some(o) = find(all, fam, model, ScenarioKind::Setpoint, d, Sel::defaults(preset)) else {
                    continue;
                };
                let m = &o.res.metrics;
                let st: Vec<String> = axes(m).iter().map(|a| fmt_opt(a.settling_s, 2)).collect();
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {:.3} | {:.3} | {} |",
                    variant_title(fam, preset),
                    model_title(model),
                    d,
                    m.final_error_m,
                    m.z.rmse_m,
                    st.join(" / ")
                );
            }
        }
    }

    let _ = writeln!(s, "\n## Control effort, constraints and compute (undisturbed)\n");
    let _ = writeln!(
        s,
        "u_norm: RMS of (U − U_hover) with each channel divided by its bound. Saturated: share of control steps \
         where the raw law left the box and was clamped. Box violation: largest commanded excursion outside the box \
         (always 0: the controllers clamp). Time: f32 controller step on this host.\n"
    );
    let _ = writeln!(
        s,
        "| controller | model | scenario | u_norm | saturated % | box violation | ns/step mean | ns/step max | \
         QP iterations mean / max (bound) |\n|---|---|---|---|---|---|---|---|---|"
    );
    for (fam, preset) in VARIANTS {
        for model in MODELS {
            for kind in SCENARIOS {
                let Some(o) = find(all, fam, model, kind, none, Sel::defaults(preset)) else {
                    continue;
                };
                let m = &o.res.metrics;
                let qp = if fam == Family::Mpc {
                    format!(
                        "{:.1} / {} ({})",
                        o.res.qp_iterations.0, o.res.qp_iterations.1, o.res.qp_iteration_bound
                    )
                } else {
                    "—".into()
                };
                let _ = writeln!(
                    s,
                    "| {} | {} | {} | {:.4} | {:.2} | {} | {:.0} | {:.0} | {} |",
                    variant_title(fam, preset),
                    model_title(model),
                    kind.name(),
                    m.u_norm,
                    100.0 * o.res.saturated_steps as f64 / o.res.steps.max(1) as f64,
                    m.max_box_violation,
                    o.res.step_time_ns.mean,
                    o.res.step_time_ns.max,
                    qp
                );
            }
        }
    }
    s
}

/// Why our numbers differ from the thesis' (kept with the generator so that a
/// regenerated table keeps its explanation).
pub const EXPLANATIONS: &str = "\
## Why the numbers differ from the thesis

- **PD roll/pitch gains.** Table 4.2 repeats Table 4.1's x/y gains (2.1/2.8, 2.15/2.5) for θ/φ. With torques \
`l·U2`, `l·U3` (docs/book/src/model.md §1) that leaves an attitude pole at −0.65 rad/s and a position cascade that is barely \
stable at ψ = 0 and unstable at ψ = 15° (the test `printed_roll_pitch_gains_leave_the_euler_pd_marginal`); the \
'printed thesis gains' rows show the result. The project's `tuned` gains change only roll/pitch (ωn ≈ 15 rad/s); \
with them the thesis' own x, y, z, ψ gains reproduce its Euler settling times to within a few hundredths of a second.
- **Quaternion PD z gains.** 550/35 asks for ≈ 2 200 m/s² on the 4 m climb. The thesis ran with U1 unbounded (its \
Fig. 4.3 shows U1 outside the box); with the box enforced the climb saturates U1 at 45 N going up but can only \
brake at 1 g, and overshoots by metres. `tuned` uses the Euler PD's position gains for the quaternion PD too, so \
its set-point numbers match the Euler PD's rather than the thesis' quaternion PD.
- **Thesis-faithful reference.** With position and velocity only (as the thesis), our numbers land in the thesis' \
range; the remaining differences come from the gains (PD) and the sampled LQR above.
- **Tracking is 10–100× tighter than the thesis.** Our controllers feed forward the reference acceleration (attitude \
and thrust) and its jerk (body rates); the thesis fed back position and velocity only. `--reference thesis` flies \
the thesis-faithful law; the test `feedforward_beats_pure_feedback_on_a_circle` measures the difference. The \
remaining x error on the circle is the start-up transient: the reference starts at 0.63 m/s while the vehicle \
starts at rest.
- **LQR settling differs by up to ~1 s.** The thesis designed a continuous LQR; ours runs the discrete LQR of the \
exact ZOH model at 500 Hz with the sampled cost. With Table 4.5's weights the continuous design has a 894 rad/s \
roll/pitch pole that 500 Hz sampling cannot reproduce, so the discrete gain is ≈ 55 % different in its fastest \
channels (test `discrete_gain_tends_to_continuous_gain`). `design lqr` prints the continuous gain and matches \
python-control to 1e-12.
- **Disturbances.** The thesis does not say what its disturbance was; ours are docs/book/src/model.md §9's. The thesis' \
PD and LQR have no integral action: `wind` pushes 0.5 N north from 5 s, which the PD's x loop (Kp 2.1 m/s² per m) \
alone would hold off by F/(m·Kp) = 0.5/(0.65·2.1) ≈ 0.37 m, and with `mismatch` (+15 % mass) the quaternion LQR \
with Table 4.7's Q = I (≈ 1 N per metre of z error) sags ≈ 2 m; the thesis' own 48 % RMSE for its disturbed \
quaternion LQR shows that weakness. The project's PD and LQR carry a disturbance observer (docs/book/src/model.md §8.6: \
force τ = 50 ms, moment τ = 1 s) and are offset-free: the set-point under `wind` ends within 3 cm while the 0.5 Hz \
gust still blows, and the helix under `wind,mismatch` stays within 0.1 m (RMSE). The thesis' disturbed numbers \
stay near its undisturbed ones, so its disturbance was much smaller or had no constant part.
- **MPC.** `thesis` runs the thesis' Appendix C problem at its 4 Hz; our set-point settles in ≈ 4.4 s against the \
thesis' 6.9–8.5 s (the thesis' MPC had no reference preview and, in MATLAB, a soft output constraint). `fast` \
re-solves at 1 kHz (every IMU sample) over a 1 s horizon with preview, feed-forward and a disturbance estimate: offset-free under \
`wind` (the set-point ends within 2 cm while the gust still blows), and stable under `mismatch` and on the \
robustness sweep's slowest rotors: the rotors' first-order lag (the vehicle's `rotor_tau_s`) is in its prediction, so \
light roll/pitch-rate weights (1.8) keep its attitude loop damped (blind to its rotors it needed 600, \
docs/book/src/mpc.md). The wind adds a few millimetres to its helix RMSE: the 0.5 Hz, 0.2 N gust sits above the \
position loop's bandwidth, so feedback alone cannot hold it off; the estimate's rate is \
extrapolated with a damped trend (T = 0.3 s), so the MPC anticipates where the gust is going rather than chasing it.
- **The `thesis` MPC is unstable under `mismatch`.** It re-plans every 0.25 s and holds \
each input for that long (zero-order hold), so the 0.178 s rotor lag and the 15 % heavier vehicle of `mismatch` \
act on an open loop for a quarter of a second at a time; the attitude oscillation grows and the flight leaves the \
reference by hundreds of metres to kilometres, on every scenario. The thesis ran its \
MPC without rotor dynamics in the loop; our `fast` preset (1 kHz) holds the same plant to centimetres.
- **Rotor lag under `mismatch`.** The plant's rotors then follow commands with τ = 0.178 s and gain 0.936, which \
the controllers do not model; it costs damping, and every controller that runs at 200 Hz or faster stays stable.
";
