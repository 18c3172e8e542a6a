//! The fast MPC's damped disturbance trend against a force whose rate is
//! known exactly: a north force ramp on the nonlinear model (RK4, 1 ms). The
//! estimated rate must equal the ramp's slope over the mass, and the trend
//! must cut the hover error the held estimate leaves behind a moving force.

use fc_core::control::{AttitudeForm, Controller, MpcConfig, MpcFast, Setpoint, StateEstimate};
use fc_core::{Disturbance, Input, QuatState, Vehicle, VehicleParams};
use nalgebra::Vector3;

/// Ramp slope of the north force, N/s, from `RAMP_START_S`.
const SLOPE_NPS: f64 = 0.15;
const RAMP_START_S: f64 = 1.0;
const END_S: f64 = 5.0;

fn rk4(v: &Vehicle<f64>, x: &QuatState<f64>, u: &Input<f64>, d: &Disturbance<f64>, h: f64) -> QuatState<f64> {
    let f = |x: &QuatState<f64>| v.quat_derivative(x, u, 0.0, d);
    let k1 = f(x);
    let k2 = f(&(x + k1 * (h / 2.0)));
    let k3 = f(&(x + k2 * (h / 2.0)));
    let k4 = f(&(x + k3 * h));
    let mut n = x + (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (h / 6.0);
    let q = n.fixed_rows::<4>(6).normalize();
    n.fixed_rows_mut::<4>(6).copy_from(&q);
    n
}

/// One control step of a hover flight: time (s), north position (m) and the
/// MPC's estimated disturbance rate (NED, m/s³) after its update.
struct Sample {
    t: f64,
    north_m: f64,
    rate: Vector3<f64>,
}

/// Hovers at (0, 0, −1) m under the north/east/down force `force_at(t)` (N)
/// for `end_s` seconds; the plant is sub-stepped 5 times per control period.
fn hover(cfg: MpcConfig, force_at: impl Fn(f64) -> Vector3<f64>, end_s: f64) -> Vec<Sample> {
    let p = VehicleParams::<f64>::os4();
    let v = Vehicle::new(&p);
    let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
    let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0);
    let mut x = QuatState::<f64>::zeros();
    x[2] = -1.0;
    x[6] = 1.0;
    let (h, sub) = (cfg.exec_dt_s / 5.0, 5);
    let mut t = 0.0;
    let mut out = Vec::new();
    while t < end_s {
        let u = mpc.update(&StateEstimate::from_quat_state(&x), &sp).unwrap().u;
        out.push(Sample {
            t,
            north_m: x[0],
            rate: mpc.disturbance_rate(),
        });
        for _ in 0..sub {
            let d = Disturbance {
                force_ned_n: force_at(t),
                moment_body_nm: Vector3::zeros(),
            };
            x = rk4(&v, &x, &u, &d, h);
            t += h;
        }
    }
    out
}

/// The ramp flight after its first second: largest north error (m) and the rates.
fn hover_under_ramp(cfg: MpcConfig) -> (f64, Vec<Vector3<f64>>) {
    let ramp = |t: f64| Vector3::new(SLOPE_NPS * (t - RAMP_START_S).max(0.0), 0.0, 0.0);
    let late: Vec<Sample> = hover(cfg, ramp, END_S)
        .into_iter()
        .filter(|s| s.t > RAMP_START_S + 1.0)
        .collect();
    let worst = late.iter().map(|s| s.north_m.abs()).fold(0.0, f64::max);
    (worst, late.iter().map(|s| s.rate).collect())
}

#[test]
fn the_trend_measures_a_force_ramp_and_cancels_its_lag() {
    let mass = VehicleParams::<f64>::os4().mass_kg;
    let truth = SLOPE_NPS / mass; // m/s³
    for form in AttitudeForm::ALL {
        let (with, rates) = hover_under_ramp(MpcConfig::fast(form));
        for r in &rates {
            assert!(
                (r[0] - truth).abs() < 0.05 * truth,
                "{form:?}: rate {} vs {truth}",
                r[0]
            );
            assert!(r[1].abs() < 0.05 * truth && r[2] == 0.0, "{form:?}: rate {r:?}");
        }
        let mut held = MpcConfig::fast(form);
        held.disturbance_trend_s = None;
        let (without, rates) = hover_under_ramp(held);
        assert!(rates.iter().all(|r| *r == Vector3::zeros()));
        eprintln!(
            "{form:?}: max north error under a {SLOPE_NPS} N/s ramp: {with:.5} m with the trend, {without:.5} m held"
        );
        assert!(
            with < 0.5 * without,
            "{form:?}: {with} m with the trend, {without} m without"
        );
    }
}

#[test]
fn the_trend_is_bounded_when_the_estimate_jumps() {
    // A force step (the estimate's rate spikes): the extrapolated change
    // |ḋ|·T stays within the configured bound at every step.
    let cfg = MpcConfig::fast(AttitudeForm::Quaternion);
    let bound = cfg.disturbance_trend_max_mps2 / cfg.disturbance_trend_s.unwrap();
    let step = |t: f64| {
        if t >= 0.1 {
            Vector3::new(3.0, -3.0, 0.0)
        } else {
            Vector3::zeros()
        }
    };
    let peak = hover(cfg, step, 1.0).iter().map(|s| s.rate.norm()).fold(0.0, f64::max);
    assert!(
        peak > 0.9 * bound,
        "the step should drive the rate to its bound: {peak}"
    );
    assert!(
        peak <= bound * 2f64.sqrt() + 1e-12,
        "rate {peak} over the bound {bound} per axis"
    );
}

#[test]
fn resuming_after_a_gap_keeps_the_disturbance_estimate() {
    // Hover 2 s under a constant 0.3 N north force, then fly 100 ms on the
    // last input with no controller step (a sensor gap), then one step.
    let p = VehicleParams::<f64>::os4();
    let v = Vehicle::new(&p);
    let cfg = MpcConfig::fast(AttitudeForm::Euler);
    let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
    let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0);
    let d = Disturbance {
        force_ned_n: Vector3::new(0.3, 0.0, 0.0),
        moment_body_nm: Vector3::zeros(),
    };
    let mut x = QuatState::<f64>::zeros();
    (x[2], x[6]) = (-1.0, 1.0);
    let h = cfg.exec_dt_s / 5.0;
    let mut u = mpc.update(&StateEstimate::from_quat_state(&x), &sp).unwrap().u;
    for _ in 0..400 {
        for _ in 0..5 {
            x = rk4(&v, &x, &u, &d, h);
        }
        u = mpc.update(&StateEstimate::from_quat_state(&x), &sp).unwrap().u;
    }
    let truth = 0.3 / p.mass_kg;
    let before = mpc.disturbance_estimate().0;
    assert!(
        (before[0] - truth).abs() < 0.02 * truth,
        "{before} vs {truth} m/s² north"
    );
    for _ in 0..500 {
        x = rk4(&v, &x, &u, &d, h); // 100 ms on the held input
    }
    let est = StateEstimate::from_quat_state(&x);
    // Resumed: the estimate is still the force's (the observer skips the
    // one prediction that would span the gap).
    let mut resumed = mpc.clone();
    resumed.resume();
    resumed.update(&est, &sp).unwrap();
    let after = resumed.disturbance_estimate().0;
    assert!((after - before).norm() < 1e-9, "{before} → {after}");
    // Not resumed: the gap is read as one 5 ms step's innovation and the
    // estimate moves (here by ≈ 5 % of the force: the held input was
    // compensating it, so the vehicle drifted little in those 100 ms).
    let mut carried_on = mpc.clone();
    carried_on.update(&est, &sp).unwrap();
    let jumped = carried_on.disturbance_estimate().0;
    assert!((jumped - before).norm() > 0.02 * truth, "{before} → {jumped}");
    // Reset (a new flight) forgets it.
    mpc.reset();
    assert_eq!(mpc.disturbance_estimate().0, Vector3::zeros());
}
