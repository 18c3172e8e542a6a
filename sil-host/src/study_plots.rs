//! The report's figures, drawn from the study's flights (and the horizon
//! sweep), in the manner of the thesis' chapter 4.

use crate::disturbance::DisturbanceSet;
use crate::figures::{decimate, Figure, Panel, Plot, Series};
use crate::flight::{fly_with, FlightConfig, FlightResult};
use crate::metrics::AxisMetrics;
use crate::scenario::{Scenario, ScenarioKind};
use crate::study::{find, variant_title, Outcome, Sel, VARIANTS};
use fc_core::control::{Family, Preset};
use fc_core::control::{Mpc, MpcConfig};
use fc_core::AttitudeForm;
use fc_core::VehicleParams;

/// Points per line: plenty for a 960-pixel figure.
const POINTS: usize = 800;

/// `(t, value)` of trace column `k` (0 x, 1 y, 2 z, 3 ψ); z is shown as
/// altitude (−z) so "up" is up.
fn column(res: &FlightResult, k: usize, reference: bool, t_max: f64) -> Vec<(f64, f64)> {
    let tr = &res.trace;
    let src = if reference { &tr.reference } else { &tr.actual };
    let sign = if k == 2 { -1.0 } else { 1.0 };
    let scale = if k == 3 { 180.0 / std::f64::consts::PI } else { 1.0 };
    let pts: Vec<(f64, f64)> =
        tr.t.iter()
            .zip(src)
            .take_while(|(t, _)| **t <= t_max)
            .map(|(t, v)| (*t, sign * scale * v[k]))
            .collect();
    decimate(&pts, POINTS)
}

/// The set-point's transient is over in a few seconds: show 10 s of it.
fn t_max(kind: ScenarioKind) -> f64 {
    if kind == ScenarioKind::Setpoint {
        10.0
    } else {
        f64::INFINITY
    }
}

fn undisturbed(all: &[Outcome], model: AttitudeForm, kind: ScenarioKind) -> Vec<(String, usize, &Outcome)> {
    VARIANTS
        .iter()
        .enumerate()
        .filter_map(|(i, (fam, preset))| {
            find(all, *fam, model, kind, DisturbanceSet::NONE, Sel::defaults(*preset))
                .map(|o| (variant_title(*fam, *preset), i, o))
        })
        .collect()
}

/// x, y, altitude against time with the reference (thesis Figs 4.14, 4.16).
fn positions(all: &[Outcome], kind: ScenarioKind) -> Option<Figure> {
    let cases = undisturbed(all, AttitudeForm::Quaternion, kind);
    let first = cases.first()?.2;
    let labels = ["x (m, north)", "y (m, east)", "altitude −z (m)"];
    let panels = (0..3)
        .map(|k| {
            let mut series = vec![Series::reference("reference", column(&first.res, k, true, t_max(kind)))];
            for (name, i, o) in &cases {
                series.push(Series::line(name.clone(), column(&o.res, k, false, t_max(kind)), *i));
            }
            Panel::new("t (s)", labels[k], series)
        })
        .collect();
    Some(Figure {
        stem: format!("position_{}", kind.name()),
        title: format!(
            "{}: position against time (quaternion form, no disturbance)",
            kind.name()
        ),
        plot: Plot::Panels(panels),
    })
}

/// The path seen from above (thesis Figs 4.15, 4.17).
fn path_top(all: &[Outcome], kind: ScenarioKind) -> Option<Figure> {
    let cases = undisturbed(all, AttitudeForm::Quaternion, kind);
    let first = cases.first()?.2;
    let xy = |res: &FlightResult, reference: bool| -> Vec<(f64, f64)> {
        let src = if reference {
            &res.trace.reference
        } else {
            &res.trace.actual
        };
        decimate(&src.iter().map(|v| (v[1], v[0])).collect::<Vec<_>>(), POINTS)
    };
    let mut series = vec![Series::reference("reference", xy(&first.res, true))];
    for (name, i, o) in &cases {
        series.push(Series::line(name.clone(), xy(&o.res, false), *i));
    }
    let mut panel = Panel::new("y (m, east)", "x (m, north)", series);
    panel.equal_axes = true;
    Some(Figure {
        stem: format!("path_top_{}", kind.name()),
        title: format!("{}: path seen from above", kind.name()),
        plot: Plot::Panels(vec![panel]),
    })
}

/// The helix in 3-D (thesis Fig 4.17).
fn path_3d(all: &[Outcome]) -> Option<Figure> {
    let cases = undisturbed(all, AttitudeForm::Quaternion, ScenarioKind::Helix);
    let first = cases.first()?.2;
    let p3 = |src: &[[f64; 4]]| decimate(&src.iter().map(|v| (v[0], v[1], -v[2])).collect::<Vec<_>>(), POINTS);
    let mut series = vec![("reference".to_string(), p3(&first.res.trace.reference), None)];
    for (name, i, o) in &cases {
        if name == "LQR" || name == "MPC fast" {
            series.push((name.clone(), p3(&o.res.trace.actual), Some(*i)));
        }
    }
    Some(Figure {
        stem: "path_3d_helix".into(),
        title: "helix: the path in 3-D (quaternion form, no disturbance)".into(),
        plot: Plot::Path3d {
            series,
            labels: ["x north m".into(), "y east m".into(), "altitude m".into()],
        },
    })
}

/// Commanded inputs with their bounds on the set-point (thesis Figs 4.1–4.13).
fn inputs(all: &[Outcome], fam: Family, preset: Preset, color: usize) -> Option<Figure> {
    let o = find(
        all,
        fam,
        AttitudeForm::Quaternion,
        ScenarioKind::Setpoint,
        DisturbanceSet::NONE,
        Sel::defaults(preset),
    )?;
    let bx = o.cfg.vehicle.input_box();
    let names = [
        "U1 thrust (N)",
        "U2 roll force (N)",
        "U3 pitch force (N)",
        "U4 yaw torque (N·m)",
    ];
    let panels = (0..4)
        .map(|k| {
            let pts: Vec<(f64, f64)> = o
                .res
                .trace
                .t
                .iter()
                .zip(&o.res.trace.u_cmd)
                .take_while(|(t, _)| **t <= t_max(ScenarioKind::Setpoint))
                .map(|(t, u)| (*t, u[k]))
                .collect();
            let mut p = Panel::new(
                "t (s)",
                names[k],
                vec![Series::line(variant_title(fam, preset), decimate(&pts, POINTS), color)],
            );
            p.bounds = vec![(bx.lo[k], "lower bound".into()), (bx.hi[k], "upper bound".into())];
            p
        })
        .collect();
    let stem = variant_title(fam, preset).to_lowercase().replace(' ', "_");
    Some(Figure {
        stem: format!("inputs_{stem}_setpoint"),
        title: format!(
            "{}: commanded inputs on the set-point step, with the input box",
            variant_title(fam, preset)
        ),
        plot: Plot::Panels(panels),
    })
}

/// Control effort per controller and scenario (thesis Fig 4.20).
fn u_norm(all: &[Outcome]) -> Figure {
    let kinds = [ScenarioKind::Setpoint, ScenarioKind::Circle, ScenarioKind::Helix];
    let mut groups = Vec::new();
    for (fam, preset) in VARIANTS {
        for model in AttitudeForm::ALL {
            let v: Vec<f64> = kinds
                .iter()
                .map(|k| {
                    find(all, fam, model, *k, DisturbanceSet::NONE, Sel::defaults(preset))
                        .map_or(0.0, |o| o.res.metrics.u_norm)
                })
                .collect();
            groups.push((format!("{} {}", variant_title(fam, preset), model.name()), v));
        }
    }
    Figure {
        stem: "u_norm".into(),
        title: "Control effort u_norm (RMS of the normalised input deviation), no disturbance".into(),
        plot: Plot::Bars {
            categories: kinds.iter().map(|k| k.name().to_string()).collect(),
            groups,
            y_label: "u_norm (dimensionless)".into(),
        },
    }
}

/// Distance from the reference against time under each disturbance (thesis
/// Figs 4.18–4.19), for the fast MPC and the LQR on the helix.
fn disturbances(all: &[Outcome]) -> Option<Figure> {
    let mut panels = Vec::new();
    for (fam, preset) in [(Family::Mpc, Preset::Project), (Family::Lqr, Preset::Project)] {
        let mut series = Vec::new();
        for (i, d) in DisturbanceSet::ALL.iter().enumerate() {
            let o = find(
                all,
                fam,
                AttitudeForm::Quaternion,
                ScenarioKind::Helix,
                *d,
                Sel::defaults(preset),
            )?;
            let tr = &o.res.trace;
            let pts: Vec<(f64, f64)> =
                tr.t.iter()
                    .zip(tr.actual.iter().zip(&tr.reference))
                    .map(|(t, (a, r))| {
                        (
                            *t,
                            ((a[0] - r[0]).powi(2) + (a[1] - r[1]).powi(2) + (a[2] - r[2]).powi(2)).sqrt(),
                        )
                    })
                    .collect();
            series.push(Series::line(d.to_string(), decimate(&pts, POINTS), i));
        }
        panels.push(Panel::new(
            "t (s)",
            format!("{}: |p − p_ref| (m)", variant_title(fam, preset)),
            series,
        ));
    }
    Some(Figure {
        stem: "disturbance_helix".into(),
        title: "helix under disturbance: distance from the reference (quaternion form)".into(),
        plot: Plot::Panels(panels),
    })
}

/// Every figure drawn from the study's flights.
pub fn study_figures(all: &[Outcome]) -> Vec<Figure> {
    let mut out = Vec::new();
    for kind in [ScenarioKind::Setpoint, ScenarioKind::Circle, ScenarioKind::Helix] {
        out.extend(positions(all, kind));
    }
    out.extend(path_top(all, ScenarioKind::Circle));
    out.extend(path_top(all, ScenarioKind::Helix));
    out.extend(path_3d(all));
    for (i, (fam, preset)) in VARIANTS.iter().enumerate() {
        out.extend(inputs(all, *fam, *preset, i));
    }
    out.push(u_norm(all));
    out.extend(disturbances(all));
    out
}

/// One point of the horizon sweep.
#[derive(Debug, Clone)]
pub struct HorizonPoint {
    /// Prediction horizon N (steps of 0.25 s).
    pub n: usize,
    /// Settling and overshoot per axis x, y, z, ψ.
    pub axes: [AxisMetrics; 4],
    /// Control effort.
    pub u_norm: f64,
    /// QP iterations (mean, max) and the a-priori bound.
    pub qp: (f64, u32, u32),
    /// Every axis settled (the closed loop is usable at this horizon).
    pub settled: bool,
}

/// Horizons of the sweep.
pub const HORIZONS: [usize; 7] = [3, 5, 8, 10, 15, 20, 30];

fn fly_horizon<const N: usize>(cfg: &FlightConfig) -> anyhow::Result<FlightResult> {
    let form = cfg.spec.form;
    let p: VehicleParams<f32> = cfg.vehicle.cast();
    let mpc = Mpc::<f32, N, 2, 8>::new(p, MpcConfig::thesis(form))
        .map_err(|e| anyhow::anyhow!("MPC N = {N}: design failed: {e:?}"))?;
    fly_with(cfg, mpc)
}

/// The thesis' study of the prediction horizon (Figs 4.9–4.10), swept: the
/// `thesis` preset (Ts 0.25 s, M 2) on the set-point with N from 3 to 30.
pub fn horizon_sweep(model: AttitudeForm, quick: bool) -> anyhow::Result<Vec<HorizonPoint>> {
    use rayon::prelude::*;
    let mut sc = Scenario::default_for(ScenarioKind::Setpoint);
    if quick {
        sc.duration_s = 12.0;
    }
    let mut cfg = FlightConfig::new(Family::Mpc, model, sc);
    cfg.spec.preset = Preset::Thesis;
    HORIZONS
        .par_iter()
        .map(|&n| {
            let r = match n {
                3 => fly_horizon::<3>(&cfg),
                5 => fly_horizon::<5>(&cfg),
                8 => fly_horizon::<8>(&cfg),
                10 => fly_horizon::<10>(&cfg),
                15 => fly_horizon::<15>(&cfg),
                20 => fly_horizon::<20>(&cfg),
                _ => fly_horizon::<30>(&cfg),
            }?;
            let m = &r.metrics;
            Ok(HorizonPoint {
                n,
                axes: [m.x, m.y, m.z, m.yaw],
                u_norm: m.u_norm,
                qp: (r.qp_iterations.0, r.qp_iterations.1, r.qp_iteration_bound),
                settled: !r.diverged && [m.x, m.y, m.z, m.yaw].iter().all(|a| a.settling_s.is_some()),
            })
        })
        .collect()
}

/// Settling time and overshoot against N.
pub fn horizon_figure(points: &[HorizonPoint]) -> Figure {
    let axes = ["x", "y", "z", "ψ"];
    let settle = (0..4)
        .map(|k| {
            let pts = points
                .iter()
                .filter(|p| p.settled)
                .filter_map(|p| p.axes[k].settling_s.map(|s| (p.n as f64, s)))
                .collect();
            Series::line(axes[k], pts, k)
        })
        .collect();
    let over = (0..4)
        .map(|k| {
            let pts = points
                .iter()
                .filter(|p| p.settled)
                .filter_map(|p| p.axes[k].overshoot_pct.map(|o| (p.n as f64, o)))
                .collect();
            Series::line(axes[k], pts, k)
        })
        .collect();
    Figure {
        stem: "horizon_sweep".into(),
        title: "MPC thesis preset (Ts 0.25 s, M 2): prediction horizon N on the set-point (settled horizons)".into(),
        plot: Plot::Panels(vec![
            Panel::new("prediction horizon N (steps of 0.25 s)", "settling time (s)", settle),
            Panel::new("prediction horizon N (steps of 0.25 s)", "overshoot (% of step)", over),
        ]),
    }
}
