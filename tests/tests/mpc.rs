//! The MPC in closed loop: offset-free under wind, never outside the input
//! box, robust to the mismatch plant, the thesis preset flying too, and the
//! QP's a-priori iteration bound never exceeded.

use e2e_tests::measure;
use fc_core::control::{Family, Preset};
use sil_host::flight::{fly, FlightConfig, FlightResult};
use sil_host::{AttitudeForm, DisturbanceSet, Scenario, ScenarioKind};

const MODELS: [AttitudeForm; 2] = AttitudeForm::ALL;

fn run(model: AttitudeForm, preset: Preset, sc: Scenario, d: &str) -> FlightResult {
    let mut cfg = FlightConfig::new(Family::Mpc, model, sc);
    cfg.spec.preset = preset;
    cfg.disturbance = d.parse::<DisturbanceSet>().unwrap();
    let r = fly(&cfg).unwrap();
    assert!(!r.diverged, "{model:?} {preset:?} {:?} {d} diverged", sc.kind);
    assert_eq!(
        r.metrics.max_box_violation, 0.0,
        "{model:?} {preset:?}: input outside the box"
    );
    assert!(
        r.qp_iterations.1 <= r.qp_iteration_bound,
        "iterations {} > bound {}",
        r.qp_iterations.1,
        r.qp_iteration_bound
    );
    r
}

#[test]
fn fast_mpc_is_offset_free_under_wind() {
    for m in MODELS {
        let r = run(
            m,
            Preset::Project,
            Scenario::default_for(ScenarioKind::Setpoint),
            "wind",
        );
        assert!(
            r.metrics.final_error_m < 0.03,
            "{m:?}: final error {} m",
            r.metrics.final_error_m
        );
        let src = "mpc::fast_mpc_is_offset_free_under_wind";
        measure(
            &format!("mpc_setpoint_wind_final_error_{}_m", m.name()),
            r.metrics.final_error_m,
            "m",
            src,
        );
    }
}

/// The fast MPC's set-point on the true state, calm: settled (2 % band)
/// sooner than the thesis' own MPC (6.9 s in x, 2.8 s in z, its Table 5.x)
/// and on the target.
#[test]
fn fast_mpc_settles_the_setpoint() {
    for m in MODELS {
        let r = run(
            m,
            Preset::Project,
            Scenario::default_for(ScenarioKind::Setpoint),
            "none",
        );
        let (x, z) = (r.metrics.x.settling_s.unwrap(), r.metrics.z.settling_s.unwrap());
        eprintln!(
            "{m:?}: settles x {x:.2} s, z {z:.2} s, final error {:.2e} m",
            r.metrics.final_error_m
        );
        assert!(x < 6.9 && z < 2.8, "{m:?}: x {x} s, z {z} s");
        assert!(
            r.metrics.final_error_m < 1e-3,
            "{m:?}: final error {}",
            r.metrics.final_error_m
        );
        let src = "mpc::fast_mpc_settles_the_setpoint";
        measure(&format!("mpc_setpoint_settling_x_{}_s", m.name()), x, "s", src);
        measure(&format!("mpc_setpoint_settling_z_{}_s", m.name()), z, "s", src);
        measure(
            &format!("mpc_setpoint_final_error_{}_m", m.name()),
            r.metrics.final_error_m,
            "m",
            src,
        );
    }
}

#[test]
fn fast_mpc_tracks_the_helix_nearly_as_well_in_wind_as_in_calm() {
    // Both flights share the start-up transient (the reference starts at
    // 0.63 m/s); the wind (force and moment steps at 5 s, 0.2 N gust at
    // 0.5 Hz) may add little to it: at most 5 mm of RMSE, and both under
    // 2 cm (issue 68: ≤ 2 cm calm, ≤ 3 cm in wind). Issue 4 asked for the
    // windy RMSE within 15 % of the calm one; with the rotors in the
    // prediction the start-up transient, most of the calm error, fell by
    // half (24 → 12 mm) while the gust's share stayed (3–4 mm), so the
    // ratio rose although the windy error fell (27 → 16 mm): the ratio is
    // measured, the added error held. x carries nearly all of the error;
    // y and z stay within a few millimetres either way (their calm RMSE is
    // below 1 mm, so their own ratio says nothing).
    for m in MODELS {
        let calm = run(m, Preset::Project, Scenario::default_for(ScenarioKind::Helix), "none");
        let windy = run(m, Preset::Project, Scenario::default_for(ScenarioKind::Helix), "wind");
        let (c, w) = (calm.metrics.position_rmse_m(), windy.metrics.position_rmse_m());
        eprintln!(
            "{m:?}: helix position RMSE {c:.5} m calm, {w:.5} m wind ({:.3}x)",
            w / c
        );
        let src = "mpc::fast_mpc_tracks_the_helix_nearly_as_well_in_wind_as_in_calm";
        for (what, r) in [("calm", &calm), ("wind", &windy)] {
            for (axis, a) in [("x", r.metrics.x), ("y", r.metrics.y), ("z", r.metrics.z)] {
                measure(
                    &format!("mpc_helix_{what}_rmse_{axis}_{}_m", m.name()),
                    a.rmse_m,
                    "m",
                    src,
                );
            }
        }
        measure(&format!("mpc_helix_wind_calm_{}_ratio", m.name()), w / c, "x", src);
        assert!(c < 0.02 && w < 0.02, "{m:?}: calm RMSE {c} m, wind {w} m");
        assert!(w - c <= 0.005, "{m:?}: wind {w} m vs calm {c} m");
        assert!(
            windy.metrics.x.rmse_m - calm.metrics.x.rmse_m <= 0.005,
            "{m:?}: x {} m vs {} m",
            windy.metrics.x.rmse_m,
            calm.metrics.x.rmse_m
        );
        for (a, b) in [(calm.metrics.y, windy.metrics.y), (calm.metrics.z, windy.metrics.z)] {
            assert!(
                a.rmse_m < 0.005 && b.rmse_m < 0.005,
                "{m:?}: {} / {}",
                a.rmse_m,
                b.rmse_m
            );
        }
    }
}

#[test]
fn fast_mpc_flies_unlisted_cases_with_wind_and_mismatch() {
    let mut fast_circle = Scenario::default_for(ScenarioKind::Circle);
    fast_circle.period_s = 6.0;
    fast_circle.radius_m = 1.5;
    fast_circle.duration_s = 30.0;
    let mut target = Scenario::default_for(ScenarioKind::Setpoint);
    target.target_ned_m = [-2.0, 4.0, -2.0];
    target.target_yaw_rad = (-120f64).to_radians();
    let mut climb = Scenario::default_for(ScenarioKind::Helix);
    climb.climb_rate_mps = 0.2;
    climb.duration_s = 40.0;
    for m in MODELS {
        for sc in [fast_circle, target, climb] {
            let r = run(m, Preset::Project, sc, "wind,mismatch");
            let worst = r.metrics.x.rmse_m.max(r.metrics.y.rmse_m).max(r.metrics.z.rmse_m);
            if sc.kind == ScenarioKind::Setpoint {
                assert!(
                    r.metrics.final_error_m < 0.15,
                    "{m:?} setpoint: final error {}",
                    r.metrics.final_error_m
                );
            } else {
                assert!(worst < 0.25, "{m:?} {:?}: worst axis RMSE {worst}", sc.kind);
            }
        }
    }
}

#[test]
fn thesis_preset_flies_the_setpoint() {
    for m in MODELS {
        let r = run(m, Preset::Thesis, Scenario::default_for(ScenarioKind::Setpoint), "none");
        assert!(
            r.metrics.final_error_m < 0.05,
            "{m:?}: final error {}",
            r.metrics.final_error_m
        );
        // 4 Hz: 20 s of flight is 81 steps.
        assert_eq!(r.steps, 81);
        let src = "mpc::thesis_preset_flies_the_setpoint";
        for (axis, a) in [
            ("x", r.metrics.x),
            ("y", r.metrics.y),
            ("z", r.metrics.z),
            ("yaw", r.metrics.yaw),
        ] {
            if let Some(t) = a.settling_s {
                measure(&format!("mpc_thesis_settling_{axis}_{}_s", m.name()), t, "s", src);
            }
        }
    }
}

#[test]
fn the_disturbance_trend_still_pays_under_sensor_noise() {
    // White sensor noise (5 mm, 2 cm/s, 0.3°, 0.6°/s at 200 Hz) is what a
    // rate estimate suffers from most. The trend's second-order rate filter
    // must keep it useful: on the windy helix it beats the held estimate,
    // and the flight stays offset-free and inside the box.
    use fc_core::control::MpcConfig;
    use sil_host::noise::SensorNoise;
    for m in MODELS {
        let fly_with = |trend: bool| {
            let mut cfg = FlightConfig::new(Family::Mpc, m, Scenario::default_for(ScenarioKind::Helix));
            cfg.disturbance = "wind".parse().unwrap();
            cfg.noise = Some(SensorNoise::typical(1.0, 1).unwrap());
            let mut c = MpcConfig::fast(m);
            if !trend {
                c.disturbance_trend_s = None;
            }
            cfg.mpc_override = Some(c);
            let r = fly(&cfg).unwrap();
            assert!(!r.diverged && r.metrics.max_box_violation == 0.0);
            r
        };
        let (with, held) = (fly_with(true), fly_with(false));
        let (a, b) = (with.metrics.x.rmse_m, held.metrics.x.rmse_m);
        eprintln!("{m:?}: noisy windy helix x RMSE {a:.5} m with the trend, {b:.5} m held");
        assert!(a < 0.95 * b, "{m:?}: {a} with the trend vs {b} held");
        assert!(
            with.metrics.final_error_m < 0.03,
            "{m:?}: final error {}",
            with.metrics.final_error_m
        );
    }
}

/// The fast MPC behind a simulator's grid (issue 29): the set-point under
/// `wind` (where the disturbance observer carries the flight) flown with
/// the flight controller stepped every 1, 2 and 3 ms and on a 2 ± 1 ms
/// jittered grid. The controller is told each interval, so the observer
/// reads no step as a disturbance and the four flights stay within 2 cm
/// of each other all the way (and end on the target).
#[test]
fn fast_mpc_flies_the_same_on_any_simulator_grid() {
    use sil_host::flight::StepGrid;
    let grids = [
        StepGrid::even(0.001),
        StepGrid::even(0.002),
        StepGrid::even(0.003),
        StepGrid {
            period_s: 0.002,
            jitter_s: 0.001,
            seed: 7,
        },
    ];
    let flights: Vec<FlightResult> = grids
        .iter()
        .map(|g| {
            let mut cfg = FlightConfig::new(
                Family::Mpc,
                AttitudeForm::Quaternion,
                Scenario::default_for(ScenarioKind::Setpoint),
            );
            cfg.disturbance = "wind".parse::<DisturbanceSet>().unwrap();
            cfg.integration_hz = 10_000.0;
            cfg.step_grid = Some(*g);
            let r = fly(&cfg).unwrap();
            assert!(!r.diverged, "{g:?}");
            assert!(
                r.metrics.final_error_m < 0.03,
                "{g:?}: final error {}",
                r.metrics.final_error_m
            );
            r
        })
        .collect();
    // Steps flown: one per grid point (3 ms: 20 s / 3 ms; jitter: about 20 s / 2 ms).
    assert_eq!(flights[0].steps, 20_001);
    assert_eq!(flights[1].steps, 10_001);
    assert_eq!(flights[2].steps, 6_667);
    assert!((9_500..10_500).contains(&flights[3].steps), "{}", flights[3].steps);
    let worst = |a: &FlightResult, b: &FlightResult| {
        a.trace
            .actual
            .iter()
            .zip(&b.trace.actual)
            .map(|(p, q)| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt())
            .fold(0.0f64, f64::max)
    };
    let mut apart = 0.0f64;
    for i in 0..flights.len() {
        for j in i + 1..flights.len() {
            let d = worst(&flights[i], &flights[j]);
            eprintln!("grids {:?} and {:?}: {d:.4} m apart at most", grids[i], grids[j]);
            assert!(d <= 0.02, "grids {:?} and {:?}: {d} m apart", grids[i], grids[j]);
            apart = apart.max(d);
        }
    }
    measure(
        "mpc_grids_apart_max_m",
        apart,
        "m",
        "mpc::fast_mpc_flies_the_same_on_any_simulator_grid",
    );
}

/// The fast preset with roll/pitch-rate weights `rate_w`, the rotors'
/// lag in the prediction or not, and moves `move_steps` long.
fn light_rates(m: AttitudeForm, rate_w: f64, lag: bool, move_steps: usize) -> fc_core::control::MpcConfig {
    let mut c = fc_core::control::MpcConfig::fast(m);
    c.q[9] = rate_w;
    c.q[10] = rate_w;
    c.rotor_lag_prediction = lag;
    c.move_steps = move_steps;
    c
}

/// A flight of the MPC configured `c` on `sc` under `d`.
fn fly_light(m: AttitudeForm, sc: Scenario, d: &str, c: fc_core::control::MpcConfig) -> FlightResult {
    let mut cfg = FlightConfig::new(Family::Mpc, m, sc);
    cfg.disturbance = d.parse().unwrap();
    cfg.mpc_override = Some(c);
    fly(&cfg).unwrap()
}

/// The rotors in the MPC's prediction (issue 68): the fast preset with
/// light roll/pitch-rate weights (2, 6 and 10; the lag-blind preset had
/// 600, the preset now 1.8) flies the
/// set-point under `mismatch`, whose plant has the OS4's 0.178 s rotor lag.
/// With the lag as states of its prediction it settles at every one of
/// them, with moves one or two prediction steps long
/// (`MpcConfig::move_steps`): the worst distance from the target over the
/// flight's last 10 s (the simulator's truth) under 1 cm. Blind to its rotors
/// (`rotor_lag_prediction` off), which is why the lag-blind preset damped
/// its attitude loop with heavy rate weights, the lightest diverges in both
/// forms (single lag-blind flights at 6 and 10 are chaotic: some diverge,
/// some hold).
#[test]
fn an_mpc_that_knows_its_rotors_needs_no_heavy_rate_weights() {
    for m in MODELS {
        let fly_with = |lag: bool, rate_w: f64, move_steps: usize| {
            let sc = Scenario::default_for(ScenarioKind::Setpoint);
            fly_light(m, sc, "mismatch", light_rates(m, rate_w, lag, move_steps))
        };
        // Worst 3-D distance from the reference over the last 10 s.
        let late_worst = |r: &FlightResult| {
            if r.diverged {
                return f64::INFINITY;
            }
            let tr = &r.trace;
            let end = tr.t.last().copied().unwrap_or(0.0);
            (0..tr.t.len())
                .filter(|&i| tr.t[i] >= end - 10.0)
                .map(|i| {
                    (0..3)
                        .map(|a| (tr.actual[i][a] - tr.reference[i][a]).powi(2))
                        .sum::<f64>()
                        .sqrt()
                })
                .fold(0.0, f64::max)
        };
        let mut worst = 0.0f64;
        for rate_w in [2.0, 6.0, 10.0] {
            let mut w = 0.0f64;
            for move_steps in [1, 2] {
                let knows = fly_with(true, rate_w, move_steps);
                assert_eq!(knows.metrics.max_box_violation, 0.0, "{m:?}: input outside the box");
                w = w.max(late_worst(&knows));
            }
            let b = late_worst(&fly_with(false, rate_w, 1));
            eprintln!(
                "{m:?}: rate weight {rate_w}, worst over the last 10 s: {w:.5} m knowing the rotors, {b:.3} m blind"
            );
            assert!(w < 0.01, "{m:?}: rate weight {rate_w}: worst {w} m over the last 10 s");
            if rate_w == 2.0 {
                assert!(
                    b > 0.1,
                    "{m:?}: blind to its rotors at rate weight 2 it held within {b} m"
                );
            }
            worst = worst.max(w);
        }
        measure(
            &format!("mpc_rotor_lag_light_rates_mismatch_hold_worst_{}_m", m.name()),
            worst,
            "m",
            "mpc::an_mpc_that_knows_its_rotors_needs_no_heavy_rate_weights",
        );
    }
}

/// The reference brought within reach (issue 68,
/// `MpcConfig::max_position_error_m`): the fast preset (the rotors in its
/// prediction, light roll/pitch-rate weights), sent to the
/// far target of `fast_mpc_flies_unlisted_cases_with_wind_and_mismatch`
/// (4.9 m away, −120°) under `wind,mismatch` (the OS4's 0.178 s rotors).
/// The prediction is linear about hover; asked for the whole 4.9 m at
/// once it saturates its torques and falls (more than 1 m below both
/// its start and its target, in both forms, then recovers). With the
/// reference at most 2.5 m ahead (the preset's cap) it never sinks more than 0.3 m below the
/// lower of the two (the simulator's truth, the whole flight) and ends on
/// the target, in both forms.
#[test]
fn a_far_target_is_approached_within_the_linear_models_reach() {
    let mut target = Scenario::default_for(ScenarioKind::Setpoint);
    target.target_ned_m = [-2.0, 4.0, -2.0];
    target.target_yaw_rad = (-120f64).to_radians();
    for m in MODELS {
        let fly_with = |cap: f64| {
            let mut c = fc_core::control::MpcConfig::fast(m);
            c.max_position_error_m = cap;
            fly_light(m, target, "wind,mismatch", c)
        };
        // How far below the lower of start and target (NED: z down) the
        // vehicle sinks, at worst over the flight.
        let sink = |r: &FlightResult| {
            if r.diverged {
                return f64::INFINITY;
            }
            let tr = &r.trace;
            let floor = tr.actual[0][2].max(target.target_ned_m[2]);
            tr.actual.iter().map(|p| p[2] - floor).fold(0.0f64, f64::max)
        };
        let (capped, uncapped) = (fly_with(2.5), fly_with(f64::INFINITY));
        let (a, b) = (sink(&capped), sink(&uncapped));
        eprintln!(
            "{m:?}: far target, sinks {a:.3} m with the reference within 2.5 m, {b:.3} m without; final error {:.4} m",
            capped.metrics.final_error_m
        );
        assert_eq!(capped.metrics.max_box_violation, 0.0, "{m:?}: input outside the box");
        assert!(a < 0.3, "{m:?}: sinks {a} m below its start and target");
        assert!(b > 1.0, "{m:?}: without the cap it sank only {b} m");
        assert!(
            capped.metrics.final_error_m < 0.15,
            "{m:?}: final error {}",
            capped.metrics.final_error_m
        );
        measure(
            &format!("mpc_far_target_sink_capped_{}_m", m.name()),
            a,
            "m",
            "mpc::a_far_target_is_approached_within_the_linear_models_reach",
        );
        measure(
            &format!("mpc_far_target_sink_uncapped_{}_m", m.name()),
            b,
            "m",
            "mpc::a_far_target_is_approached_within_the_linear_models_reach",
        );
    }
}

/// Why the thesis preset does not hold `mismatch` (issue 68): re-planning
/// at 4 Hz, it holds only the rotors it predicts. On the helix under
/// `wind,mismatch` (the plant with the OS4's 0.178 s rotor lag) it diverges
/// blind to the lag, as the study shows, and holds with the lag in its
/// prediction ([`fc_core::control::MpcConfig::rotor_lag_prediction`]);
/// but with the lag in its prediction it diverges on the nominal plant,
/// whose rotors deliver at once. A model error of 0.178 s is most of a
/// 250 ms step, either way; the fast preset re-plans every 1 ms and holds
/// both (`fast_mpc_tracks_the_helix_nearly_as_well_in_wind_as_in_calm`,
/// `fast_mpc_flies_unlisted_cases_with_wind_and_mismatch`).
/// "Fails": diverged, or ending more than 1 m from the reference.
#[test]
fn the_thesis_preset_holds_only_the_rotors_it_predicts() {
    let helix = Scenario::default_for(ScenarioKind::Helix);
    for m in MODELS {
        let fly_thesis = |d: &str, lag: bool| {
            let mut cfg = FlightConfig::new(Family::Mpc, m, helix);
            cfg.spec.preset = Preset::Thesis;
            let mut c = fc_core::control::MpcConfig::thesis(m);
            c.rotor_lag_prediction = lag;
            cfg.mpc_override = Some(c);
            cfg.disturbance = d.parse().unwrap();
            fly(&cfg).unwrap()
        };
        let fails = |r: &FlightResult| r.diverged || r.metrics.final_error_m > 1.0;
        let verdict = |r: &FlightResult| if fails(r) { "fails" } else { "holds" };
        let blind = fly_thesis("wind,mismatch", false);
        let knows = fly_thesis("wind,mismatch", true);
        let knows_nominal = fly_thesis("none", true);
        let worst_axis = |r: &FlightResult| r.metrics.x.rmse_m.max(r.metrics.y.rmse_m).max(r.metrics.z.rmse_m);
        eprintln!(
            "{m:?}: thesis preset on the helix: wind,mismatch blind {} / knowing the lag {} (worst axis {:.4} m); \
             nominal knowing the lag {}",
            verdict(&blind),
            verdict(&knows),
            worst_axis(&knows),
            verdict(&knows_nominal),
        );
        assert!(fails(&blind), "{m:?}: blind to the lag it held wind,mismatch");
        assert!(!fails(&knows), "{m:?}: knowing the lag it failed wind,mismatch");
        assert_eq!(knows.metrics.max_box_violation, 0.0, "{m:?}: input outside the box");
        assert!(fails(&knows_nominal), "{m:?}: knowing a lag the plant lacks it held");
        measure(
            &format!("mpc_thesis_lag_wind_mismatch_helix_worst_axis_{}_m", m.name()),
            worst_axis(&knows),
            "m",
            "mpc::the_thesis_preset_holds_only_the_rotors_it_predicts",
        );
    }
}
