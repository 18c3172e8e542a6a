//! Flying from sensors: the on-board estimator against the true state of
//! the SIL's plant (issue "Fly from sensors"): its accuracy, its
//! consistency (NEES against the χ² band), flying on it against flying on
//! the truth, convergence from a bad start, and each fault.

use e2e_tests::measure;
use fc_core::control::{Family, StateEstimate};
use fc_core::estimate::{Eskf, EskfConfig};
use fc_core::{euler_to_quat, hover_input, hover_quat_state, quat_mul};
use nalgebra::{Vector3, Vector4};
use sil_host::disturbance::DisturbanceSet;
use sil_host::estimation::EstimationResult;
use sil_host::flight::{fly, FlightConfig, FlightResult};
use sil_host::plant::{Plant, PlantConfig};
use sil_host::sensors::{attitude_error, FixProfile, SensorConfig, Sensors, IMU_PERIOD_S};
use sil_host::{AttitudeForm, Scenario, ScenarioKind};

fn sensed(family: Family, kind: ScenarioKind, profile: FixProfile, seed: u64) -> FlightConfig {
    let mut cfg = FlightConfig::new(family, AttitudeForm::Quaternion, Scenario::default_for(kind));
    cfg.sensors = Some(SensorConfig::new(profile, seed));
    cfg
}

fn est(r: &FlightResult) -> &EstimationResult {
    r.estimation.as_ref().expect("a sensor flight reports its estimator")
}

fn rmse3(r: &FlightResult) -> f64 {
    let m = &r.metrics;
    (m.x.rmse_m.powi(2) + m.y.rmse_m.powi(2) + m.z.rmse_m.powi(2)).sqrt()
}

#[test]
fn mocap_on_the_helix_estimates_within_the_issue_bounds() {
    for d in [DisturbanceSet::NONE, "wind,mismatch".parse::<DisturbanceSet>().unwrap()] {
        let mut cfg = sensed(Family::Lqr, ScenarioKind::Helix, FixProfile::Mocap, 1);
        cfg.disturbance = d;
        let r = fly(&cfg).unwrap();
        let e = est(&r);
        assert!(!r.diverged);
        let src = "estimation::mocap_on_the_helix_estimates_within_the_issue_bounds";
        let what = if d == DisturbanceSet::NONE {
            "calm"
        } else {
            "wind_mismatch"
        };
        measure(&format!("est_mocap_helix_{what}_att_deg"), e.rms_att_deg, "deg", src);
        measure(&format!("est_mocap_helix_{what}_pos_m"), e.rms_pos_m, "m", src);
        measure(&format!("est_mocap_helix_{what}_vel_mps"), e.rms_vel_mps, "m/s", src);
        assert!(e.rms_att_deg <= 0.3, "{d}: attitude {:.3}°", e.rms_att_deg);
        assert!(e.rms_pos_m <= 0.005, "{d}: position {:.4} m", e.rms_pos_m);
        assert!(e.rms_vel_mps <= 0.02, "{d}: velocity {:.4} m/s", e.rms_vel_mps);
        let c = e.counters;
        // A true fix fails the joint 5σ gate with probability 1.5e-5
        // (χ²(3) > 25): of a flight's 10 000 mocap fixes, 0.15 on average.
        // Two is already unlikely; more is a filter that believes itself.
        assert!(c.pos_rejected <= 2, "{d}: {c:?}");
        assert_eq!((c.yaw_rejected, c.imu_rejected), (0, 0), "{d}: {c:?}");
        assert_eq!(e.failsafe_steps, 0, "{d}");
        // It aligned at once: 25 samples at rest.
        assert!(e.aligning_steps <= 26, "{d}: {}", e.aligning_steps);
    }
}

#[test]
fn gps_holds_position_within_thirty_centimetres_for_ten_minutes() {
    let mut cfg = sensed(Family::Lqr, ScenarioKind::Helix, FixProfile::Gps, 2);
    cfg.scenario.duration_s = 600.0;
    let r = fly(&cfg).unwrap();
    let e = est(&r);
    assert!(!r.diverged);
    let src = "estimation::gps_holds_position_within_thirty_centimetres_for_ten_minutes";
    measure("est_gps_helix_pos_m", e.rms_pos_m, "m", src);
    assert!(e.rms_pos_m <= 0.3, "position RMS {:.3} m", e.rms_pos_m);
    assert!(e.max_pos_m <= 1.5, "largest position error {:.3} m", e.max_pos_m);
    assert_eq!(e.failsafe_steps, 0);
    // The vehicle flies as well as its fixes allow: within a metre of the helix.
    assert!(rmse3(&r) < 0.5, "tracking {:.3} m", rmse3(&r));
}

/// Tracking on the estimate against tracking on the truth, helix calm and
/// with wind and a mismatched vehicle: PD within 1.5×, LQR within 1.3×.
#[test]
fn flying_on_the_estimate_tracks_nearly_as_well_as_on_the_truth() {
    // The product controllers (the fast MPC at 200 Hz over the 1 kHz
    // estimator) on the helix; the MPC's flights are 30 s (debug builds).
    let mut ratios: Vec<(Family, f64)> = Vec::new();
    for d in [DisturbanceSet::NONE, "wind,mismatch".parse::<DisturbanceSet>().unwrap()] {
        for (family, bound) in [(Family::Pd, 1.5), (Family::Lqr, 1.3), (Family::Mpc, 1.3)] {
            for form in [AttitudeForm::Euler, AttitudeForm::Quaternion] {
                let mut cfg = FlightConfig::new(family, form, Scenario::default_for(ScenarioKind::Helix));
                cfg.disturbance = d;
                if family == Family::Mpc {
                    cfg.scenario.duration_s = 30.0;
                }
                let truth = rmse3(&fly(&cfg).unwrap());
                cfg.sensors = Some(SensorConfig::new(FixProfile::Mocap, 1));
                let ekf = rmse3(&fly(&cfg).unwrap());
                ratios.push((family, ekf / truth));
                assert!(
                    ekf <= bound * truth,
                    "{family:?} {form:?} {d}: {ekf:.4} m on the estimate, {truth:.4} m on the truth"
                );
            }
        }
    }
    let src = "estimation::flying_on_the_estimate_tracks_nearly_as_well_as_on_the_truth";
    for (family, name) in [(Family::Pd, "pd"), (Family::Lqr, "lqr"), (Family::Mpc, "mpc")] {
        let r: Vec<f64> = ratios.iter().filter(|(f, _)| *f == family).map(|(_, r)| *r).collect();
        let (lo, hi) = (
            r.iter().copied().fold(f64::INFINITY, f64::min),
            r.iter().copied().fold(0.0, f64::max),
        );
        measure(&format!("est_over_truth_{name}_min_ratio"), lo, "x", src);
        measure(&format!("est_over_truth_{name}_max_ratio"), hi, "x", src);
    }
}

/// Over 50 seeds, the average NEES at each instant must lie in the 95 %
/// band of χ²(50·15)/50 at least 90 % of the time (Bar-Shalom's test of a
/// filter's consistency: its errors are as large as it claims, no larger).
#[test]
fn the_filter_is_consistent_over_fifty_seeds() {
    let runs = 50;
    let mut sums: Vec<f64> = Vec::new();
    // χ²(15) 2.5 % and 97.5 % points.
    let band15 = 6.262_1..=27.488_4;
    let (mut inside_runs, mut samples) = (0usize, 0usize);
    for seed in 0..runs {
        let mut cfg = sensed(Family::Lqr, ScenarioKind::Helix, FixProfile::Mocap, 100 + seed);
        cfg.scenario.duration_s = 10.0;
        let r = fly(&cfg).unwrap();
        let trace = &est(&r).trace;
        if sums.is_empty() {
            sums = vec![0.0; trace.len()];
        }
        assert_eq!(trace.len(), sums.len());
        for (s, x) in sums.iter_mut().zip(trace) {
            *s += x.nees;
        }
        for x in trace.iter().skip(100) {
            samples += 1;
            inside_runs += usize::from(band15.contains(&x.nees));
        }
    }
    // Each run's NEES in its own 95 % band (15 dof), from 1 s on (the first
    // second is the filter converging from its alignment).
    let per_run = inside_runs as f64 / samples as f64;
    // Wilson–Hilferty: χ²_p(k) ≈ k (1 − 2/(9k) + z_p √(2/(9k)))³.
    let k = (runs * 15) as f64;
    let q = |z: f64| k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3) / runs as f64;
    let (lo, hi) = (q(-1.959_964), q(1.959_964));
    let anees: Vec<f64> = sums.iter().skip(100).map(|s| s / runs as f64).collect();
    let inside = anees.iter().filter(|a| (lo..=hi).contains(*a)).count() as f64 / anees.len() as f64;
    let mean = anees.iter().sum::<f64>() / anees.len() as f64;
    eprintln!(
        "NEES of each run inside [6.26, 27.49] {:.1} % of the time; the 50-run average inside \
         [{lo:.2}, {hi:.2}] {:.1} %, mean {mean:.2}",
        100.0 * per_run,
        100.0 * inside
    );
    let src = "estimation::the_filter_is_consistent_over_fifty_seeds";
    measure("nees_inside_band_pct", 100.0 * per_run, "%", src);
    measure("nees_mean", mean, "", src);
    assert!(
        per_run >= 0.9,
        "each run's NEES inside its 95 % band only {:.1} % of the time",
        100.0 * per_run
    );
    // The average says the same, more sharply: neither overconfident nor timid.
    assert!(
        (12.0..=18.0).contains(&mean),
        "mean NEES {mean:.2}, 15 for a consistent filter"
    );
}

/// From a 30° attitude error and 1 m of position error, hovering under
/// mocap, the filter is back within 1° and 1 cm in 2 s. (It first grows
/// overconfident about a tilt it has half corrected, rejects the fixes that
/// disagree, and after `reset_after_rejections` of them resets position and
/// velocity and widens its attitude: then it converges, in ≈ 0.8 s.)
#[test]
fn the_filter_converges_from_thirty_degrees_and_a_metre() {
    let x0 = hover_quat_state(&Vector3::new(0.0, 0.0, -1.0), 0.4);
    let mut plant = Plant::new(PlantConfig::nominal(AttitudeForm::Quaternion), &x0);
    let dt = 0.002;
    let mut sensors = Sensors::new(SensorConfig::new(FixProfile::Mocap, 5), dt).unwrap();
    let mut f = Eskf::<128>::new(EskfConfig::BMI088).unwrap();
    let truth_q = Vector4::new(x0[6], x0[7], x0[8], x0[9]);
    let wrong = StateEstimate {
        pos_ned_m: Vector3::new(0.6, -0.6, -1.0 + 0.53).cast(), // 1.0 m off
        vel_ned_mps: Vector3::zeros(),
        att: quat_mul(&euler_to_quat(0.3, -0.4, 0.0), &truth_q).cast(), // 30° off
        rates_frd_radps: Vector3::zeros(),
    };
    let att0 = attitude_error(&truth_q, &wrong.att.cast()).norm().to_degrees();
    assert!((att0 - 28.6).abs() < 1.0, "{att0}");
    f.start_at(&wrong, 1.0, 0.1, 0.6).unwrap();
    let u = hover_input(&plant.config().params);
    for k in 0..1000 {
        let r = sensors.read(k as f64 * dt, &plant);
        f.predict(&r.imu, dt as f32).unwrap();
        for fix in &r.fixes {
            f.fuse(fix).unwrap();
        }
        plant.step(&u, dt);
    }
    let x = plant.quat_state();
    let e = f.estimate().unwrap();
    let att = attitude_error(&Vector4::new(x[6], x[7], x[8], x[9]), &e.att.cast())
        .norm()
        .to_degrees();
    let pos = (Vector3::new(x[0], x[1], x[2]) - e.pos_ned_m.cast::<f64>()).norm();
    assert!(att < 1.0, "attitude error after 2 s: {att:.3}°");
    assert!(pos < 0.01, "position error after 2 s: {pos:.4} m");
}

#[test]
fn an_outlier_is_rejected_and_a_two_second_outage_is_flown_on_dead_reckoning() {
    let mut cfg = sensed(Family::Lqr, ScenarioKind::Helix, FixProfile::Mocap, 3);
    cfg.scenario.duration_s = 20.0;
    let clean = fly(&cfg).unwrap();
    if let Some(s) = cfg.sensors.as_mut() {
        s.faults.outlier_at_s = Some(4.0);
        s.faults.outage = Some((8.0, 2.0));
    }
    let r = fly(&cfg).unwrap();
    let e = est(&r);
    assert_eq!(e.counters.pos_rejected, 1, "{:?}", e.counters);
    assert_eq!(e.failsafe_entries, 0, "2 s of dead reckoning is within the limit");
    // Dead reckoning on a BMI088 for 2 s stays within centimetres.
    assert!(e.max_pos_m < 0.05, "largest position error {:.3} m", e.max_pos_m);
    assert!(
        rmse3(&r) < 1.2 * rmse3(&clean) + 0.005,
        "{} vs {}",
        rmse3(&r),
        rmse3(&clean)
    );
}

#[test]
fn a_ten_second_outage_enters_the_failsafe_and_recovers() {
    let mut cfg = sensed(Family::Lqr, ScenarioKind::Setpoint, FixProfile::Mocap, 4);
    cfg.scenario.duration_s = 30.0;
    if let Some(s) = cfg.sensors.as_mut() {
        s.faults.outage = Some((8.0, 10.0));
    }
    let r = fly(&cfg).unwrap();
    let e = est(&r);
    assert!(!r.diverged);
    assert_eq!(e.failsafe_entries, 1);
    // The failsafe begins 5 s into the outage (the dead-reckoning limit) and
    // ends when fixes return: ≈ 5 s of IMU steps.
    let fs = e.failsafe_steps as f64 * IMU_PERIOD_S;
    assert!((4.8..5.3).contains(&fs), "failsafe for {fs:.2} s");
    // Recovered: back on the set-point by the end (12 s after the outage).
    assert!(
        r.metrics.final_error_m < 0.05,
        "final error {:.3} m",
        r.metrics.final_error_m
    );
}

#[test]
fn bad_imu_samples_are_counted_and_flown_through() {
    let mut cfg = sensed(Family::Lqr, ScenarioKind::Helix, FixProfile::Mocap, 6);
    cfg.scenario.duration_s = 10.0;
    let clean = fly(&cfg).unwrap();
    if let Some(s) = cfg.sensors.as_mut() {
        s.faults.imu_nan_at_s = Some(2.0);
        s.faults.accel_clip_at_s = Some(3.0);
        s.faults.imu_stuck = Some((4.0, 0.05));
    }
    let r = fly(&cfg).unwrap();
    let e = est(&r);
    assert_eq!(
        (e.counters.imu_rejected, e.counters.imu_clipped),
        (1, 1),
        "{:?}",
        e.counters
    );
    assert_eq!(e.failsafe_entries, 0);
    let c = est(&clean);
    assert!(
        e.rms_pos_m < c.rms_pos_m + 0.001,
        "{:.4} m vs {:.4} m",
        e.rms_pos_m,
        c.rms_pos_m
    );
    assert!(
        e.rms_att_deg < c.rms_att_deg + 0.05,
        "{:.3}° vs {:.3}°",
        e.rms_att_deg,
        c.rms_att_deg
    );
    assert!(rmse3(&r) < 1.1 * rmse3(&clean) + 0.002);
}
