//! Closed-loop flights of every PD and LQR variant in the SIL (f32 controller
//! at 500 Hz, f64 plant at 1 kHz): set-point accuracy, tracking RMSE, faster
//! circles than the thesis flew, inputs always inside the box.

use fc_core::control::{Family, ReferenceMode};
use sil_host::flight::{fly, FlightConfig, FlightResult};
use sil_host::{AttitudeForm, Scenario, ScenarioKind};

const VARIANTS: [(Family, AttitudeForm); 4] = [
    (Family::Pd, AttitudeForm::Euler),
    (Family::Pd, AttitudeForm::Quaternion),
    (Family::Lqr, AttitudeForm::Euler),
    (Family::Lqr, AttitudeForm::Quaternion),
];

fn run(c: Family, m: AttitudeForm, sc: Scenario) -> FlightResult {
    let res = fly(&FlightConfig::new(c, m, sc)).unwrap();
    assert!(!res.diverged, "{c:?} {m:?} {:?} diverged", sc.kind);
    assert_eq!(
        res.metrics.max_box_violation, 0.0,
        "{c:?} {m:?}: command outside the box"
    );
    res
}

#[test]
fn every_variant_reaches_the_setpoint() {
    for (c, m) in VARIANTS {
        let r = run(c, m, Scenario::default_for(ScenarioKind::Setpoint));
        assert!(
            r.metrics.final_error_m < 0.05,
            "{c:?} {m:?}: final error {}",
            r.metrics.final_error_m
        );
        // Every axis settles (2 % band) well inside the 20 s flight.
        for (name, a) in [
            ("x", r.metrics.x),
            ("y", r.metrics.y),
            ("z", r.metrics.z),
            ("yaw", r.metrics.yaw),
        ] {
            let s = a.settling_s.unwrap_or(f64::INFINITY);
            assert!(s < 10.0, "{c:?} {m:?} {name} settles at {s}");
        }
    }
}

#[test]
fn every_variant_tracks_circle_and_helix() {
    for kind in [ScenarioKind::Circle, ScenarioKind::Helix] {
        for (c, m) in VARIANTS {
            let r = run(c, m, Scenario::default_for(kind));
            for (name, a) in [("x", r.metrics.x), ("y", r.metrics.y), ("z", r.metrics.z)] {
                assert!(a.rmse_m <= 0.2, "{c:?} {m:?} {kind:?} {name}: RMSE {} m", a.rmse_m);
            }
        }
    }
}

#[test]
fn every_variant_tracks_faster_circles() {
    // Four times the thesis' angular rate (5 s per turn, 1.5 m radius: 1.9 m/s,
    // 2.4 m/s² centripetal) and a 6 s helix climbing 0.3 m/s.
    let mut fast = Scenario::default_for(ScenarioKind::Circle);
    fast.period_s = 5.0;
    fast.radius_m = 1.5;
    fast.duration_s = 30.0;
    let mut helix = Scenario::default_for(ScenarioKind::Helix);
    helix.period_s = 6.0;
    helix.climb_rate_mps = 0.3;
    helix.duration_s = 30.0;
    for sc in [fast, helix] {
        for (c, m) in VARIANTS {
            let r = run(c, m, sc);
            for (name, a) in [("x", r.metrics.x), ("y", r.metrics.y), ("z", r.metrics.z)] {
                assert!(
                    a.rmse_m <= 0.2,
                    "{c:?} {m:?} fast {:?} {name}: RMSE {} m",
                    sc.kind,
                    a.rmse_m
                );
            }
        }
    }
}

#[test]
fn feedforward_beats_pure_feedback_on_a_circle() {
    // The thesis-faithful reference (position and velocity only) lags a moving
    // reference; feeding the acceleration forward removes most of that lag.
    let mut sc = Scenario::default_for(ScenarioKind::Circle);
    sc.period_s = 8.0;
    sc.duration_s = 24.0;
    for (c, m) in VARIANTS {
        let mut cfg = FlightConfig::new(c, m, sc);
        let ff = fly(&cfg).unwrap().metrics;
        cfg.spec.reference = ReferenceMode::Thesis;
        let th = fly(&cfg).unwrap().metrics;
        let (e_ff, e_th) = (ff.x.rmse_m.hypot(ff.y.rmse_m), th.x.rmse_m.hypot(th.y.rmse_m));
        assert!(e_ff < 0.7 * e_th, "{c:?} {m:?}: feed-forward {e_ff} vs thesis {e_th}");
    }
}
