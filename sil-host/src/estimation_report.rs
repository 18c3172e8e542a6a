//! The report's "Flying from sensors" section: every product controller on
//! the helix flown on the true state and on the on-board estimate (mocap),
//! side by side, one gps flight, and the estimation error of one flight
//! against its ±3σ band (one figure per state group).

use crate::disturbance::DisturbanceSet;
use crate::estimation::EstSample;
use crate::figures::{decimate, Figure, Panel, Plot, Series};
use crate::flight::FlightConfig;
use crate::scenario::{Scenario, ScenarioKind};
use crate::sensors::{FixProfile, SensorConfig};
use crate::study::{run_all, Outcome};
use anyhow::Result;
use fc_core::control::{Family, Preset};
use fc_core::AttitudeForm;
use std::fmt::Write;

/// The flights of the section: (controller, disturbance) × (truth, ekf+mocap)
/// on the helix, quaternion form, then an LQR helix on gps.
pub fn flights(quick: bool) -> Vec<FlightConfig> {
    let mut helix = Scenario::default_for(ScenarioKind::Helix);
    if quick {
        helix.duration_s = 30.0;
    }
    let mut out = Vec::new();
    for d in [DisturbanceSet::NONE, "wind,mismatch".parse().expect("a valid set")] {
        for family in [Family::Pd, Family::Lqr, Family::Mpc] {
            // The project presets: PD tuned, the LQR, the fast MPC.
            let mut cfg = FlightConfig::new(family, AttitudeForm::Quaternion, helix);
            cfg.spec.preset = Preset::Project;
            cfg.disturbance = d;
            out.push(cfg);
            cfg.sensors = Some(SensorConfig::new(FixProfile::Mocap, 1));
            out.push(cfg);
        }
    }
    let mut gps = FlightConfig::new(Family::Lqr, AttitudeForm::Quaternion, helix);
    gps.sensors = Some(SensorConfig::new(FixProfile::Gps, 1));
    out.push(gps);
    out
}

/// Flies [`flights`].
pub fn run(quick: bool, progress: bool) -> Result<Vec<Outcome>> {
    run_all(&flights(quick), progress)
}

fn rmse3(o: &Outcome) -> f64 {
    o.res.metrics.position_rmse_m()
}

/// The section's markdown (tables; the figures are linked by the caller).
pub fn markdown(out: &[Outcome]) -> String {
    let mut s = String::new();
    s.push_str(
        "\n## Flying from sensors\n\nThe product controllers on the helix (quaternion form), flown once on the true \
         state and once from simulated sensors — a BMI088 IMU at 1 kHz and mocap fixes (100 Hz, 2 mm, 10 ms \
         late, heading 0.5°) — through the on-board error-state Kalman filter (`sil-host fly --estimator ekf`, the \
         default), which steps at every IMU sample; the controller runs on its own schedule above it (PD and LQR \
         every 2 ms, the fast MPC every 5 ms), as on a vehicle. Tracking: position RMSE of the true state, m. Estimation: RMS error of the estimate against the \
         truth. NEES: mean of `eᵀP⁻¹e` over the flight, 15 for a consistent filter (`tests/tests/estimation.rs` checks \
         the χ² band over 50 seeds). The issue's bounds: tracking on the estimate within 1.3× (LQR, MPC) and 1.5× (PD) \
         of the truth; attitude ≤ 0.3°, position ≤ 5 mm, velocity ≤ 2 cm/s.\n\n\
         | controller | disturbance | RMSE truth m | RMSE estimate m | ratio | bound | attitude ° | position mm | velocity cm/s | NEES |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut over = false;
    for pair in out.chunks(2).filter(|p| p.len() == 2 && p[0].cfg.sensors.is_none()) {
        let (t, e) = (&pair[0], &pair[1]);
        let Some(est) = &e.res.estimation else { continue };
        let bound = if t.cfg.spec.family == Family::Pd { 1.5 } else { 1.3 };
        let ratio = rmse3(e) / rmse3(t);
        over |= ratio > bound;
        let _ = writeln!(
            s,
            "| {} | {} | {:.4} | {:.4} | {:.2}{} | {bound} | {:.3} | {:.2} | {:.2} | {:.1} |",
            crate::study::variant_title(t.cfg.spec.family, t.cfg.spec.preset),
            t.cfg.disturbance,
            rmse3(t),
            rmse3(e),
            ratio,
            if ratio <= bound { "" } else { " (over)" },
            est.rms_att_deg,
            est.rms_pos_m * 1e3,
            est.rms_vel_mps * 1e2,
            est.nees_mean,
        );
    }
    if let Some(g) = out
        .iter()
        .find(|o| o.cfg.sensors.is_some_and(|s| s.profile == FixProfile::Gps))
    {
        if let Some(est) = &g.res.estimation {
            let _ = writeln!(
                s,
                "\nThe LQR on **gps** (10 Hz, 0.3/0.5 m, 100 ms late, with barometer and magnetometer), same helix: \
                 tracking RMSE {:.3} m; estimate RMS error {:.3} m (largest {:.3} m), {:.2} cm/s, {:.2}°; NEES {:.1}; \
                 failsafe steps {}.",
                rmse3(g),
                est.rms_pos_m,
                est.max_pos_m,
                est.rms_vel_mps * 1e2,
                est.rms_att_deg,
                est.nees_mean,
                est.failsafe_steps
            );
        }
    }
    if over {
        s.push_str(
            "\nA row marked (over) misses the issue's bound (`tests/tests/estimation.rs` fails on it for the \
             product controllers).\n",
        );
    }
    s
}

/// Error of one group (`first` state index, three axes) and its ±3σ band,
/// scaled to display units.
fn group_panels(trace: &[EstSample], first: usize, unit: &str, scale: f64, axes: [&str; 3]) -> Vec<Panel> {
    let pts = decimate(trace, 2000);
    (0..3)
        .map(|a| {
            let i = first + a;
            let err: Vec<(f64, f64)> = pts.iter().map(|s| (s.t, s.err[i] * scale)).collect();
            let hi: Vec<(f64, f64)> = pts.iter().map(|s| (s.t, 3.0 * s.sigma[i] * scale)).collect();
            let lo: Vec<(f64, f64)> = pts.iter().map(|s| (s.t, -3.0 * s.sigma[i] * scale)).collect();
            Panel::new(
                "t (s)",
                format!("{} error ({unit})", axes[a]),
                vec![
                    Series::line("truth − estimate", err, 0),
                    Series::reference("±3σ (the filter's claim)", hi),
                    Series::reference("", lo),
                ],
            )
        })
        .collect()
}

/// The ±3σ figures of the calm LQR flight on mocap: position, velocity,
/// attitude, gyro bias, accelerometer bias.
pub fn figures(out: &[Outcome]) -> Vec<Figure> {
    let Some(o) = out.iter().find(|o| {
        o.cfg.spec.family == Family::Lqr
            && o.cfg.disturbance == DisturbanceSet::NONE
            && o.cfg.sensors.is_some_and(|s| s.profile == FixProfile::Mocap)
    }) else {
        return Vec::new();
    };
    let Some(est) = &o.res.estimation else {
        return Vec::new();
    };
    let t = &est.trace;
    // (file stem, title, first error-state index, unit, scale to the unit, axes)
    type Group<'a> = (&'a str, &'a str, usize, &'a str, f64, [&'a str; 3]);
    let groups: [Group; 5] = [
        ("position", "Position", 0, "mm", 1e3, ["north", "east", "down"]),
        ("velocity", "Velocity", 3, "cm/s", 1e2, ["north", "east", "down"]),
        (
            "attitude",
            "Attitude",
            6,
            "°",
            180.0 / std::f64::consts::PI,
            ["about north", "about east", "about down"],
        ),
        (
            "gyro_bias",
            "Gyro bias",
            9,
            "°/s",
            180.0 / std::f64::consts::PI,
            ["p", "q", "r"],
        ),
        (
            "accel_bias",
            "Accelerometer bias",
            12,
            "mg",
            1e3 / 9.80665,
            ["x (front)", "y (right)", "z (down)"],
        ),
    ];
    groups
        .iter()
        .map(|(stem, title, first, unit, scale, axes)| Figure {
            stem: format!("estimate_{stem}"),
            title: format!("{title} estimation error and the filter's ±3σ, LQR on the helix, BMI088 + mocap (seed 1)"),
            plot: Plot::Panels(group_panels(t, *first, unit, *scale, *axes)),
        })
        .collect()
}
