//! Plant tests against independent truth: equilibria, closed-form responses,
//! agreement of the two state forms, the 90° pitch case, RK4's order.

use fc_core::{
    hover_input, hover_quat_state, quat_to_rotation, realised_inputs, rotor_speeds, QuatState, VehicleParams,
};
use nalgebra::{Matrix3, Vector3, Vector4};
use sil_host::{AttitudeForm, DisturbanceSet, Plant, PlantConfig};

const MODELS: [AttitudeForm; 2] = AttitudeForm::ALL;

fn start() -> QuatState<f64> {
    hover_quat_state(&Vector3::new(0.0, 0.0, -1.0), 0.0)
}

fn fly(cfg: PlantConfig, x0: &QuatState<f64>, u: Vector4<f64>, secs: f64, dt: f64) -> Plant {
    let mut p = Plant::new(cfg, x0);
    let n = (secs / dt).round() as usize;
    for _ in 0..n {
        p.step(&u, dt);
    }
    p
}

#[test]
fn hover_is_an_equilibrium_of_both_plants() {
    for m in MODELS {
        for lag in [false, true] {
            let mut cfg = PlantConfig::nominal(m);
            cfg.rotor_lag = lag;
            // With lag the rotors settle at k·Ω_cmd: command the hover speed / k.
            let p = VehicleParams::OS4;
            let u = if lag {
                let w = Vector4::repeat(p.hover_rotor_speed_radps() / p.rotor_gain);
                realised_inputs(&p, &w)
            } else {
                hover_input(&p)
            };
            let x0 = hover_quat_state(&Vector3::new(1.0, 2.0, -3.0), 0.4);
            let pl = fly(cfg, &x0, u, 10.0, 0.002);
            assert!(
                (pl.quat_state() - x0).amax() < 1e-9,
                "{m:?} lag={lag}: {}",
                pl.quat_state() - x0
            );
        }
    }
}

#[test]
fn free_fall_reaches_terminal_speed() {
    // U = 0: rotors stop; ż obeys m z̈ = m g − ktz ż, so ż(t) = (mg/ktz)(1 − e^{−ktz t/m}).
    let p = VehicleParams::OS4;
    let vt = p.hover_thrust_n() / p.kt_nspm[2];
    let tau = p.mass_kg / p.kt_nspm[2];
    for m in MODELS {
        let mut pl = Plant::new(PlantConfig::nominal(m), &start());
        let mut z_expected;
        for k in 1..=60 {
            pl.step(&Vector4::zeros(), 1.0);
            let t = k as f64;
            let vz = pl.quat_state()[5];
            let want = vt * (1.0 - (-t / tau).exp());
            assert!((vz - want).abs() < 1e-9 * vt, "{m:?} t={t}: {vz} vs {want}");
            z_expected = -1.0 + vt * (t - tau * (1.0 - (-t / tau).exp()));
            assert!((pl.position()[2] - z_expected).abs() < 1e-7, "{m:?} z at {t}");
        }
        // After 60 s (≈14 τ) the speed is the terminal one, mg/ktz = 42.51 m/s.
        assert!((pl.quat_state()[5] - vt).abs() < 1e-4 * vt);
        assert!((vt - 42.51).abs() < 0.01);
        // Nothing else moved.
        let x = pl.quat_state();
        assert!(x[0].abs() < 1e-12 && x[1].abs() < 1e-12 && (x[6] - 1.0).abs() < 1e-12);
    }
}

#[test]
fn yaw_spin_up_reaches_u4_over_krz() {
    // Hover thrust plus U4: ṙ = (U4 − krz r)/Iz, r → U4/krz with time constant Iz/krz.
    let p = VehicleParams::OS4;
    let u4 = 0.02;
    let u = Vector4::new(p.hover_thrust_n(), 0.0, 0.0, u4);
    let tau = p.inertia_kgm2[2] / p.kr_nms[2];
    for m in MODELS {
        let mut pl = Plant::new(PlantConfig::nominal(m), &start());
        for k in 1..=200 {
            pl.step(&u, 0.01);
            let t = k as f64 * 0.01;
            let r = pl.quat_state()[12];
            let want = u4 / p.kr_nms[2] * (1.0 - (-t / tau).exp());
            assert!((r - want).abs() < 1e-10, "{m:?} t={t}: {r} vs {want}");
        }
        // Hover holds: realised U1 is still mg, so altitude does not change.
        assert!((pl.position()[2] + 1.0).abs() < 1e-9);
        assert!((pl.quat_state()[12] - u4 / p.kr_nms[2]).abs() < 1e-6);
    }
}

#[test]
fn euler_and_quaternion_plants_agree() {
    // A manoeuvre with thrust, roll, pitch and yaw inputs and gyroscopic coupling,
    // with and without rotor lag and wind: the two forms must fly the same path.
    let u = Vector4::new(6.6, 0.004, -0.003, 0.02);
    for (lag, wind) in [(false, false), (true, false), (false, true)] {
        let run = |m| {
            let mut cfg = PlantConfig::nominal(m).with_disturbance(DisturbanceSet { wind, mismatch: false });
            cfg.rotor_lag = lag;
            let mut pl = Plant::new(cfg, &start());
            let mut worst = 0.0f64;
            let mut path = Vec::new();
            for _ in 0..300 {
                pl.step(&u, 0.01);
                path.push(pl.position());
            }
            (path, pl.euler_state(), &mut worst).0.clone()
        };
        let (pe, pq) = (run(AttitudeForm::Euler), run(AttitudeForm::Quaternion));
        let worst = pe.iter().zip(&pq).map(|(a, b)| (a - b).norm()).fold(0.0, f64::max);
        // The manoeuvre is real: it moves the vehicle by decimetres.
        assert!((pe.last().unwrap() - Vector3::new(0.0, 0.0, -1.0)).norm() > 0.1);
        assert!(worst < 1e-6, "lag={lag} wind={wind}: max |Δpos| = {worst:e} m");
    }
}

#[test]
fn quaternion_plant_flies_through_ninety_degrees_pitch() {
    // Constant pitch force and a small yaw torque, no thrust: the vehicle tumbles
    // nose-up through θ = 90°. Truth: body rates (independent of attitude) and a
    // rotation matrix Ṙ = R [ω]× integrated alongside with fine RK4 steps.
    let mut p = VehicleParams::OS4;
    p.rotor_inertia_kgm2 = 0.0; // keep ωr out so rates have a simple truth
    let mut cfg = PlantConfig::nominal(AttitudeForm::Quaternion);
    cfg.params = p;
    let u = Vector4::new(4.0, 0.0, 0.6, 0.01);
    let ur = realised_inputs(&p, &rotor_speeds(&p, &u));
    let mut pl = Plant::new(cfg, &start());
    let skew = |w: &Vector3<f64>| Matrix3::new(0.0, -w[2], w[1], w[2], 0.0, -w[0], -w[1], w[0], 0.0);
    let fr = |r: &Matrix3<f64>, w: &Vector3<f64>| {
        let [ix, iy, iz] = p.inertia_kgm2;
        let [kx, ky, kz] = p.kr_nms;
        let wd = Vector3::new(
            (p.arm_m * ur[1] - kx * w[0] + (iy - iz) * w[1] * w[2]) / ix,
            (p.arm_m * ur[2] - ky * w[1] + (iz - ix) * w[0] * w[2]) / iy,
            (ur[3] - kz * w[2] + (ix - iy) * w[0] * w[1]) / iz,
        );
        (r * skew(w), wd)
    };
    let mut r = Matrix3::identity();
    let mut w = Vector3::zeros();
    let h = 1e-5;
    let mut max_pitch = f64::MIN;
    let mut crossed = false;
    for _ in 0..150 {
        pl.step(&u, 0.01);
        for _ in 0..1000 {
            let (k1r, k1w) = fr(&r, &w);
            let (k2r, k2w) = fr(&(r + k1r * (h / 2.0)), &(w + k1w * (h / 2.0)));
            let (k3r, k3w) = fr(&(r + k2r * (h / 2.0)), &(w + k2w * (h / 2.0)));
            let (k4r, k4w) = fr(&(r + k3r * h), &(w + k3w * h));
            r += (k1r + k2r * 2.0 + k3r * 2.0 + k4r) * (h / 6.0);
            w += (k1w + k2w * 2.0 + k3w * 2.0 + k4w) * (h / 6.0);
        }
        let x = pl.quat_state();
        let q = x.fixed_rows::<4>(6).into_owned();
        assert!((q.norm() - 1.0).abs() < 1e-12);
        assert!(x.iter().all(|v| v.is_finite()));
        let rq = quat_to_rotation(&q);
        assert!(
            (rq - r).amax() < 1e-6,
            "t={}: R differs by {}",
            pl.time(),
            (rq - r).amax()
        );
        // Pitch measured from the body x axis' elevation: passes +90° when R31 reaches −1.
        let pitch = (-rq[(2, 0)]).clamp(-1.0, 1.0).asin();
        max_pitch = max_pitch.max(pitch);
        if rq[(2, 2)] < 0.0 {
            crossed = true; // body z points up: the nose went past vertical
        }
    }
    assert!(
        max_pitch > 85.0f64.to_radians() && crossed,
        "max pitch {}",
        max_pitch.to_degrees()
    );
}

#[test]
fn rk4_error_falls_sixteen_fold_when_step_halves() {
    // Coarse integration rates on a vigorous manoeuvre; truth from a 64× finer step.
    let u = Vector4::new(9.0, 0.05, -0.04, 0.05);
    let at = |hz: f64| {
        let mut cfg = PlantConfig::nominal(AttitudeForm::Quaternion);
        cfg.integration_hz = hz;
        let pl = fly(cfg, &start(), u, 2.0, 0.1);
        pl.quat_state()
    };
    let truth = at(50.0 * 64.0);
    let e1 = (at(50.0) - truth).norm();
    let e2 = (at(100.0) - truth).norm();
    let e3 = (at(200.0) - truth).norm();
    let (r1, r2) = (e1 / e2, e2 / e3);
    assert!(
        (12.0..20.0).contains(&r1) && (12.0..20.0).contains(&r2),
        "ratios {r1} {r2} (errors {e1:e} {e2:e} {e3:e})"
    );
}

#[test]
fn rotor_lag_is_first_order_with_gain() {
    // Rotors from hover speed to a new command: Ω(t) = kΩc + (Ω0 − kΩc) e^{−t/τ},
    // for the OS4's τ, a slow 0.2 s and a near-instant 10 µs (far below the
    // 1 ms step, where an RK4 of the lag itself diverges).
    for tau in [VehicleParams::OS4.rotor_tau_s, 0.2, 1e-5] {
        let mut p = VehicleParams::OS4;
        p.rotor_tau_s = tau;
        let mut cfg = PlantConfig::nominal(AttitudeForm::Quaternion);
        cfg.params = p;
        cfg.rotor_lag = true;
        let u = Vector4::new(8.0, 0.0, 0.0, 0.0);
        let wc = rotor_speeds(&p, &u)[0];
        let w0 = p.hover_rotor_speed_radps();
        let mut pl = Plant::new(cfg, &start());
        for k in 1..=100 {
            pl.step(&u, 0.01);
            let t = k as f64 * 0.01;
            let want = p.rotor_gain * wc + (w0 - p.rotor_gain * wc) * (-t / tau).exp();
            let got = pl.rotor_speeds();
            assert!(
                got.iter().all(|w| (w - want).abs() < 1e-9),
                "τ={tau} t={t}: {got} vs {want}"
            );
        }
        assert!(pl.position().iter().all(|v| v.is_finite()));
    }
}

#[test]
fn a_near_instant_rotor_lag_flies_like_no_lag() {
    // τ = 10 µs with the command scaled by 1/k: the rotors sit at the
    // commanded speed within a sub-step, so the flight is the lag-free one
    // (to the lag's first 10 µs of each command change).
    let mut p = VehicleParams::OS4;
    p.rotor_tau_s = 1e-5;
    let fly = |lag: bool| {
        let mut cfg = PlantConfig::nominal(AttitudeForm::Quaternion);
        cfg.params = p;
        cfg.rotor_lag = lag;
        let mut pl = Plant::new(cfg, &start());
        for k in 0..2000 {
            // A command that changes every 10 ms: a small roll doublet on hover.
            let roll = if (k / 10) % 2 == 0 { 0.01 } else { -0.01 };
            let u = Vector4::new(p.hover_thrust_n(), roll, 0.0, 0.0);
            let w = rotor_speeds(&p, &u) / if lag { p.rotor_gain } else { 1.0 };
            let u = realised_inputs(&p, &w);
            pl.step(&u, 0.001);
        }
        pl.position()
    };
    let (a, b) = (fly(true), fly(false));
    assert!((a - b).amax() < 1e-4, "{a} vs {b}");
}

#[test]
fn wind_pushes_the_hovering_vehicle_along_its_force() {
    // Hover input, wind from 5 s: before 5 s nothing moves; afterwards the NED
    // force (0.5+gust, −0.3, 0.2) N accelerates the vehicle north, west(−y), down.
    let u = hover_input(&VehicleParams::OS4);
    let cfg = PlantConfig::nominal(AttitudeForm::Quaternion).with_disturbance("wind".parse().unwrap());
    let mut pl = Plant::new(cfg, &start());
    for _ in 0..500 {
        pl.step(&u, 0.01);
    }
    assert!((pl.position() - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
    pl.step(&u, 0.1);
    let v = pl.quat_state().fixed_rows::<3>(3).into_owned();
    let m = VehicleParams::OS4.mass_kg;
    // Over 0.1 s: Δv ≈ ∫F dt / m, the gust contributing 0.2(1 − cos 0.1π)/π N·s on x.
    // The moment tilts the thrust by a few mrad, which changes Δv by ~1e-3 m/s.
    let gust = 0.2 * (1.0 - (0.1 * std::f64::consts::PI).cos()) / std::f64::consts::PI;
    let want = Vector3::new(0.5 * 0.1 + gust, -0.3 * 0.1, 0.2 * 0.1) / m;
    assert!((v - want).amax() < 2e-3, "{v} vs {want}");
}

#[test]
fn mismatch_changes_the_true_vehicle() {
    let cfg = PlantConfig::nominal(AttitudeForm::Euler).with_disturbance("mismatch".parse().unwrap());
    assert!(cfg.rotor_lag);
    assert!((cfg.params.mass_kg - 0.65 * 1.15).abs() < 1e-12);
    assert!((cfg.params.inertia_kgm2[2] - 1.3e-2 * 1.1).abs() < 1e-12);
    assert!((cfg.params.kt_nspm[2] - 0.225).abs() < 1e-12);
    // Heavier vehicle under the nominal hover input sinks.
    let pl = fly(cfg, &start(), hover_input(&VehicleParams::OS4), 1.0, 0.01);
    assert!(pl.position()[2] > -1.0 + 0.1);
    assert!("bogus".parse::<DisturbanceSet>().is_err());
}

#[test]
fn a_steady_wind_carries_the_hovering_vehicle_at_its_speed() {
    // Hover thrust, a 3 m/s wind along north-east: drag acts on the velocity
    // relative to the air, so each horizontal axis obeys m v̇ = kt (w − v):
    // v(t) = w (1 − e^{−kt t/m}), and the vehicle ends up moving with the air.
    let p = VehicleParams::OS4;
    let w = Vector3::new(3.0, -2.0, 0.0);
    for m in MODELS {
        let mut cfg = PlantConfig::nominal(m);
        cfg.wind_ned_mps = w;
        let mut pl = Plant::new(cfg, &start());
        let u = Vector4::new(p.hover_thrust_n(), 0.0, 0.0, 0.0);
        for k in 1..=20 {
            pl.step(&u, 0.5);
            let t = 0.5 * k as f64;
            let x = pl.quat_state();
            for i in 0..2 {
                let want = w[i] * (1.0 - (-p.kt_nspm[i] * t / p.mass_kg).exp());
                assert!(
                    (x[3 + i] - want).abs() < 1e-9,
                    "{m:?} t={t} axis {i}: {} vs {want}",
                    x[3 + i]
                );
            }
            assert!(x[5].abs() < 1e-9, "no vertical motion");
        }
    }
}
