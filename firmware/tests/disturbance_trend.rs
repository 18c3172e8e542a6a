//! The fast MPC's damped disturbance trend against a force whose rate is
//! known exactly: a north force ramp on the nonlinear model (RK4, 1 ms). The
//! estimated rate must equal the ramp's slope over the mass, and the trend
//! must cut the hover error the held estimate leaves behind a moving force.

use firmware::control::{Controller, MpcConfig, MpcFast, MpcForm, Setpoint, StateEstimate};
use firmware::{Disturbance, Input, QuatState, Vehicle, VehicleParams};
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

struct Run {
    /// Largest north position error after the first second of the ramp, m.
    max_error_m: f64,
    /// Estimated disturbance rate (NED, m/s³) at each control step after it.
    rates: Vec<Vector3<f64>>,
}

fn hover_under_ramp(cfg: MpcConfig) -> Run {
    let p = VehicleParams::<f64>::os4();
    let v = Vehicle::new(&p);
    let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
    let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0);
    let mut x = QuatState::<f64>::zeros();
    x[2] = -1.0;
    x[6] = 1.0;
    let (dt, sub) = (cfg.exec_dt_s, 5);
    let mut t = 0.0;
    let mut run = Run {
        max_error_m: 0.0,
        rates: Vec::new(),
    };
    while t < END_S {
        let u = mpc.update(&StateEstimate::from_quat_state(&x), &sp).unwrap().u;
        if t > RAMP_START_S + 1.0 {
            run.max_error_m = run.max_error_m.max(x[0].abs());
            run.rates.push(mpc.disturbance_rate());
        }
        for _ in 0..sub {
            let mut d = Disturbance::none();
            d.force_ned_n[0] = SLOPE_NPS * (t - RAMP_START_S).max(0.0);
            x = rk4(&v, &x, &u, &d, dt / sub as f64);
            t += dt / sub as f64;
        }
    }
    run
}

#[test]
fn the_trend_measures_a_force_ramp_and_cancels_its_lag() {
    let mass = VehicleParams::<f64>::os4().mass_kg;
    let truth = SLOPE_NPS / mass; // m/s³
    for form in [MpcForm::Euler, MpcForm::Quaternion] {
        let with = hover_under_ramp(MpcConfig::fast(form));
        for r in &with.rates {
            assert!(
                (r[0] - truth).abs() < 0.05 * truth,
                "{form:?}: rate {} vs {truth}",
                r[0]
            );
            assert!(r[1].abs() < 0.05 * truth && r[2] == 0.0, "{form:?}: rate {r:?}");
        }
        let mut held = MpcConfig::fast(form);
        held.disturbance_trend_s = None;
        let without = hover_under_ramp(held);
        assert!(without.rates.iter().all(|r| *r == Vector3::zeros()));
        eprintln!(
            "{form:?}: max north error under a {SLOPE_NPS} N/s ramp: {:.5} m with the trend, {:.5} m held",
            with.max_error_m, without.max_error_m
        );
        assert!(
            with.max_error_m < 0.5 * without.max_error_m,
            "{form:?}: {} m with the trend, {} m without",
            with.max_error_m,
            without.max_error_m
        );
    }
}

#[test]
fn the_trend_is_bounded_when_the_estimate_jumps() {
    // A force step (the estimate's rate spikes): the extrapolated change
    // |ḋ|·T stays within the configured bound at every step.
    let p = VehicleParams::<f64>::os4();
    let cfg = MpcConfig::fast(MpcForm::Quaternion);
    let bound = cfg.disturbance_trend_max_mps2 / cfg.disturbance_trend_s.unwrap();
    let v = Vehicle::new(&p);
    let mut mpc = MpcFast::<f64>::new(p, cfg).unwrap();
    let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0);
    let mut x = QuatState::<f64>::zeros();
    x[2] = -1.0;
    x[6] = 1.0;
    let mut peak = 0.0f64;
    for k in 0..200 {
        let u = mpc.update(&StateEstimate::from_quat_state(&x), &sp).unwrap().u;
        peak = peak.max(mpc.disturbance_rate().norm());
        let mut d = Disturbance::none();
        if k >= 20 {
            d.force_ned_n = Vector3::new(3.0, -3.0, 0.0);
        }
        for _ in 0..5 {
            x = rk4(&v, &x, &u, &d, 0.001);
        }
    }
    assert!(
        peak > 0.9 * bound,
        "the step should drive the rate to its bound: {peak}"
    );
    assert!(
        peak <= bound * 2f64.sqrt() + 1e-12,
        "rate {peak} over the bound {bound} per axis"
    );
}
