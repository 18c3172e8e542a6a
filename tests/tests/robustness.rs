//! Issue 15's closed-loop claims, flown in the SIL: the project's PD and LQR
//! are offset-free (their disturbance observer, docs/book/src/model.md §8.6) where
//! the thesis' printed controllers are not, every project controller tracks
//! the helix under `wind,mismatch` within 0.1 m, and the robustness sweep's
//! worst corner (slow rotors, little rotational drag, heavy inertia, strong
//! rotors, latency, wind) is flown inside the tube — the corner where the
//! first tuned PD's attitude loop failed the Routh condition of §8.6.

use fc_core::control::{Family, Preset};
use sil_host::disturbance::Uncertainty;
use sil_host::flight::{fly, FlightConfig, FlightResult};
use sil_host::{AttitudeForm, DisturbanceSet, Scenario, ScenarioKind};

/// The project's controllers (the product), every family and form.
fn project() -> impl Iterator<Item = (Family, AttitudeForm)> {
    Family::ALL
        .into_iter()
        .flat_map(|f| AttitudeForm::ALL.into_iter().map(move |m| (f, m)))
}

fn config(f: Family, m: AttitudeForm, preset: Preset, kind: ScenarioKind, d: &str) -> FlightConfig {
    let mut cfg = FlightConfig::new(f, m, Scenario::default_for(kind));
    cfg.spec.preset = preset;
    cfg.disturbance = d.parse::<DisturbanceSet>().unwrap();
    cfg
}

fn flown(cfg: &FlightConfig) -> FlightResult {
    let r = fly(cfg).unwrap();
    assert!(!r.diverged, "{} diverged", cfg.spec);
    assert_eq!(r.metrics.max_box_violation, 0.0, "{}: input outside the box", cfg.spec);
    r
}

/// Largest distance from the reference over the flight, m.
fn max_error(r: &FlightResult) -> f64 {
    r.trace
        .actual
        .iter()
        .zip(&r.trace.reference)
        .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt())
        .fold(0.0, f64::max)
}

#[test]
fn integral_action_holds_the_setpoint_against_wind() {
    // `wind`: 0.5 N north (and −0.3, 0.2 N), moment steps and a 0.2 N,
    // 0.5 Hz gust that still blows at the end. A proportional loop holds a
    // constant force off by F/(m·Kp) ≈ 0.37 m; with the observer the
    // remaining error is the gust's.
    for (f, m) in project() {
        let r = flown(&config(f, m, Preset::Project, ScenarioKind::Setpoint, "wind"));
        assert!(
            r.metrics.final_error_m < 0.03,
            "{f:?} {m:?}: final error {} m",
            r.metrics.final_error_m
        );
    }
    // The thesis' PD and LQR (no observer) keep the steady offset: the
    // observer, not the gains, removes it.
    for f in [Family::Pd, Family::Lqr] {
        let r = flown(&config(
            f,
            AttitudeForm::Euler,
            Preset::Thesis,
            ScenarioKind::Setpoint,
            "wind",
        ));
        assert!(
            r.metrics.final_error_m > 0.2,
            "{f:?} thesis: final error {} m",
            r.metrics.final_error_m
        );
    }
}

#[test]
fn every_project_controller_tracks_the_helix_under_wind_and_mismatch() {
    for (f, m) in project() {
        let r = flown(&config(f, m, Preset::Project, ScenarioKind::Helix, "wind,mismatch"));
        let worst = [r.metrics.x.rmse_m, r.metrics.y.rmse_m, r.metrics.z.rmse_m]
            .into_iter()
            .fold(0.0, f64::max);
        assert!(worst <= 0.1, "{f:?} {m:?}: worst-axis RMSE {worst} m");
    }
}

#[test]
fn the_sweeps_worst_corner_is_flown_inside_the_tube() {
    let corner = Uncertainty {
        mass_scale: 0.8,
        inertia_scale: [1.3; 3],
        drag_scale: 0.5,
        rotor_tau_s: Some(0.2),
        kf_scale: 1.1,
        wind_ned_mps: [2.1, -2.1, 0.0],
        latency_s: 0.005,
    };
    for (f, m) in project() {
        let mut cfg = config(f, m, Preset::Project, ScenarioKind::Helix, "none");
        cfg.scenario.duration_s = 30.0;
        cfg.uncertainty = Some(corner);
        let r = flown(&cfg);
        let e = max_error(&r);
        assert!(e < 1.0, "{f:?} {m:?}: {e} m from the reference");
    }
}
