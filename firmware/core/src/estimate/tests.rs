//! The filter against analytic cases: alignment at rest, a constant
//! rotation, a vehicle at rest with noisy fixes (the steady state of a
//! known linear filter), bad samples and fixes, and a finite-difference
//! check of its transition matrix (in `eskf.rs`, which can see it).

use super::*;
use crate::control::StateEstimate;
use crate::model::{euler_to_quat, quat_to_euler, quat_to_rotation};
use nalgebra::{Vector3, Vector4};

const DT: f32 = 0.002;
type Filter = Eskf<64>;

/// The IMU of a vehicle at rest with attitude `q`: specific force `Rᵀ(0,0,−g)`.
fn at_rest(q: &Vector4<f32>, gyro_bias: Vector3<f32>) -> ImuSample {
    let r = quat_to_rotation(q);
    ImuSample {
        gyro_frd_radps: gyro_bias,
        accel_frd_mps2: r.transpose() * Vector3::new(0.0, 0.0, -9.81),
    }
}

fn mocap(pos: Vector3<f32>, yaw: f32) -> Fix {
    Fix {
        pos_ned_m: Some(pos),
        pos_sigma_m: Vector3::repeat(0.002),
        yaw_rad: Some(yaw),
        yaw_sigma_rad: 0.5f32.to_radians(),
        ..Fix::EMPTY
    }
}

/// Small deterministic normal draws (a 32-bit LCG and Box–Muller).
struct Draws(u32);
impl Draws {
    fn uniform(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        ((self.0 >> 8) as f32 + 0.5) / (1u32 << 24) as f32
    }
    fn normal(&mut self) -> f32 {
        let (u1, u2) = (self.uniform(), self.uniform());
        libm::sqrtf(-2.0 * libm::logf(u1)) * libm::cosf(2.0 * core::f32::consts::PI * u2)
    }
}

#[test]
fn alignment_at_rest_recovers_tilt_heading_and_gyro_bias() {
    let (phi, theta, psi) = (0.10f32, -0.05, 2.0);
    let q = euler_to_quat(phi, theta, psi);
    let bias = Vector3::new(0.01, -0.02, 0.005);
    let mut f = Filter::new(EskfConfig::BMI088).unwrap();
    assert_eq!(f.estimate(), Err(EstimatorError::NotAligned));
    for k in 0..30 {
        f.predict(&at_rest(&q, bias), DT).unwrap();
        if k == 3 {
            f.fuse(&mocap(Vector3::new(1.0, 2.0, -3.0), psi)).unwrap();
        }
    }
    assert_eq!(f.mode(), Mode::Running);
    let e = f.estimate().unwrap();
    let ang = quat_to_euler(&e.att);
    assert!((ang - Vector3::new(phi, theta, psi)).amax() < 1e-4, "{ang:?}");
    assert!((e.pos_ned_m - Vector3::new(1.0, 2.0, -3.0)).amax() < 1e-3);
    // The rates the controllers see are the measured ones less the bias: zero at rest.
    assert!(e.rates_frd_radps.amax() < 1e-6);
    assert!((f.biases().0 - bias).amax() < 1e-6);
}

#[test]
fn alignment_waits_for_a_heading_and_a_position() {
    let q = euler_to_quat(0.0, 0.0, 0.0);
    let mut f = Filter::new(EskfConfig::BMI088).unwrap();
    for _ in 0..100 {
        f.predict(&at_rest(&q, Vector3::zeros()), DT).unwrap();
    }
    f.fuse(&Fix {
        pos_ned_m: Some(Vector3::zeros()),
        pos_sigma_m: Vector3::repeat(0.01),
        ..Fix::EMPTY
    })
    .unwrap();
    assert_eq!(f.mode(), Mode::Aligning, "no heading yet");
    f.fuse(&mocap(Vector3::zeros(), 0.3)).unwrap();
    assert_eq!(f.mode(), Mode::Running);
}

#[test]
fn a_constant_rotation_is_integrated_exactly() {
    // Spinning about body x at 1 rad/s for 1 s, no gravity term involved in
    // the attitude: roll must reach 1 rad (to f32 rounding over 500 steps).
    let mut f = Filter::new(EskfConfig::BMI088).unwrap();
    let est = StateEstimate {
        pos_ned_m: Vector3::zeros(),
        vel_ned_mps: Vector3::zeros(),
        att: Vector4::new(1.0, 0.0, 0.0, 0.0),
        rates_frd_radps: Vector3::zeros(),
    };
    f.start_at(&est, 0.01, 0.01, 0.01).unwrap();
    for _ in 0..500 {
        let sample = ImuSample {
            gyro_frd_radps: Vector3::new(1.0, 0.0, 0.0),
            accel_frd_mps2: Vector3::zeros(), // free fall: no specific force
        };
        f.predict(&sample, DT).unwrap();
    }
    let e = f.estimate().unwrap();
    assert!((quat_to_euler(&e.att)[0] - 1.0).abs() < 1e-4);
    // Free fall for 1 s from rest: 9.81 m/s down, 4.905 m fallen.
    assert!((e.vel_ned_mps[2] - 9.81).abs() < 1e-3, "{}", e.vel_ned_mps[2]);
    assert!((e.pos_ned_m[2] - 4.905).abs() < 1e-3, "{}", e.pos_ned_m[2]);
}

/// At rest with noisy position fixes only, the position variance of each
/// axis must settle where the scalar steady-state Kalman filter of that
/// axis settles; the actual errors must agree with it.
#[test]
fn at_rest_the_errors_match_the_covariance() {
    let q = euler_to_quat(0.0, 0.0, 0.5);
    let mut f = Filter::new(EskfConfig::BMI088).unwrap();
    let mut g = Draws(7);
    let cfg = EskfConfig::BMI088;
    let sig_a = cfg.accel_noise / libm::sqrtf(DT);
    let sig_g = cfg.gyro_noise / libm::sqrtf(DT);
    let mut sq = Vector3::<f64>::zeros();
    let mut var = Vector3::<f64>::zeros();
    let mut n = 0.0;
    for k in 0..20_000 {
        let mut s = at_rest(&q, Vector3::zeros());
        for i in 0..3 {
            s.accel_frd_mps2[i] += sig_a * g.normal();
            s.gyro_frd_radps[i] += sig_g * g.normal();
        }
        f.predict(&s, DT).unwrap();
        if k % 5 == 0 {
            let noise = Vector3::new(g.normal(), g.normal(), g.normal()) * 0.002;
            f.fuse(&mocap(noise, 0.5 + 0.5f32.to_radians() * g.normal())).unwrap();
        }
        if k > 5_000 {
            let e = f.estimate().unwrap();
            let d = f.covariance().diagonal();
            for i in 0..3 {
                sq[i] += f64::from(e.pos_ned_m[i]).powi(2);
                var[i] += f64::from(d[i]);
            }
            n += 1.0;
        }
    }
    for i in 0..3 {
        let (mse, p) = (sq[i] / n, var[i] / n);
        // The filter claims what it achieves (within sampling error) ...
        assert!(mse < 2.0 * p && mse > 0.5 * p, "axis {i}: mse {mse:e}, P {p:e}");
        // ... and averages fixes: better than one fix (2 mm).
        assert!(p.sqrt() < 0.002, "axis {i}: σ {}", p.sqrt());
    }
    assert_eq!(f.counters().pos_rejected, 0);
}

#[test]
fn bad_samples_and_fixes_are_counted_and_never_enter() {
    let q = euler_to_quat(0.0, 0.0, 0.0);
    let mut f = Filter::new(EskfConfig::BMI088).unwrap();
    for _ in 0..30 {
        f.predict(&at_rest(&q, Vector3::zeros()), DT).unwrap();
    }
    f.fuse(&mocap(Vector3::zeros(), 0.0)).unwrap();
    let before = f.estimate().unwrap();
    let nan = ImuSample {
        gyro_frd_radps: Vector3::new(f32::NAN, 0.0, 0.0),
        accel_frd_mps2: Vector3::zeros(),
    };
    let inf = ImuSample {
        gyro_frd_radps: Vector3::zeros(),
        accel_frd_mps2: Vector3::new(0.0, f32::INFINITY, 0.0),
    };
    let spin = ImuSample {
        gyro_frd_radps: Vector3::new(100.0, 0.0, 0.0), // beyond ±2000 °/s
        accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
    };
    let clipped = ImuSample {
        gyro_frd_radps: Vector3::zeros(),
        accel_frd_mps2: Vector3::new(0.0, 0.0, -24.0 * 9.81),
    };
    for s in [nan, inf, spin, clipped] {
        f.predict(&s, DT).unwrap();
    }
    let c = f.counters();
    assert_eq!((c.imu_rejected, c.imu_clipped), (3, 1));
    // Flown on the last good sample: still at rest, level.
    let after = f.estimate().unwrap();
    assert!((after.pos_ned_m - before.pos_ned_m).amax() < 1e-4);
    assert!(quat_to_euler(&after.att).amax() < 1e-4);
    // A fix where it is: test ratios well inside the gate.
    f.fuse(&mocap(Vector3::zeros(), 0.0)).unwrap();
    let r = f.test_ratios();
    assert!(r.pos_horiz < 0.2 && r.pos_vert < 0.2 && r.yaw < 0.2, "{r:?}");
    // A 5 m outlier fails the gate; the estimate does not move. Its
    // north ratio is (5 m)² / (gate² · (P_nn + σ²)), PX4's definition, far
    // above 1; down is untouched.
    let s_nn = f.covariance()[(0, 0)] + 0.002 * 0.002;
    f.fuse(&mocap(Vector3::new(5.0, 0.0, 0.0), 0.0)).unwrap();
    assert_eq!(f.counters().pos_rejected, 1);
    assert!(f.estimate().unwrap().pos_ned_m.amax() < 1e-3);
    let r = f.test_ratios();
    let gate = EskfConfig::BMI088.gate_sigma;
    let want = 25.0 / (gate * gate * s_nn);
    assert!(
        want > 1e4 && (r.pos_horiz / want - 1.0).abs() < 1e-3,
        "{} vs {want}",
        r.pos_horiz
    );
    assert!(r.pos_vert < 0.2, "{r:?}");
    // Refused before gating: bad sigma, non-finite value, negative age.
    let mut bad = mocap(Vector3::zeros(), 0.0);
    bad.pos_sigma_m[1] = 0.0;
    assert_eq!(f.fuse(&bad), Err(EstimatorError::FixSigma));
    bad = mocap(Vector3::new(f32::NAN, 0.0, 0.0), 0.0);
    assert_eq!(f.fuse(&bad), Err(EstimatorError::FixValue));
    bad = mocap(Vector3::zeros(), 0.0);
    bad.age_s = -1.0;
    assert_eq!(f.fuse(&bad), Err(EstimatorError::FixAge));
    bad.age_s = 10.0; // older than the filter: skipped, not an error
    assert_eq!(f.fuse(&bad), Ok(()));
    for _ in 0..64 {
        f.predict(&at_rest(&q, Vector3::zeros()), DT).unwrap();
    }
    // Older than the 64 steps of a full history: refused.
    assert_eq!(f.fuse(&bad), Err(EstimatorError::FixAge));
    assert_eq!(f.counters().fix_invalid, 4);
    assert_eq!(
        f.predict(&at_rest(&q, Vector3::zeros()), f32::NAN),
        Err(EstimatorError::Step)
    );
}

#[test]
fn a_persistent_jump_is_believed_after_the_configured_rejections() {
    let q = euler_to_quat(0.0, 0.0, 0.0);
    let mut f = Filter::new(EskfConfig::BMI088).unwrap();
    for _ in 0..30 {
        f.predict(&at_rest(&q, Vector3::zeros()), DT).unwrap();
    }
    f.fuse(&mocap(Vector3::zeros(), 0.0)).unwrap();
    let n = EskfConfig::BMI088.reset_after_rejections;
    for _ in 0..n {
        f.predict(&at_rest(&q, Vector3::zeros()), DT).unwrap();
        f.fuse(&mocap(Vector3::new(5.0, 0.0, 0.0), 0.0)).unwrap();
    }
    let c = f.counters();
    assert_eq!((c.pos_rejected, c.pos_resets), (u32::from(n), 1));
    assert!((f.estimate().unwrap().pos_ned_m[0] - 5.0).abs() < 1e-2);
}

#[test]
fn a_delayed_fix_is_compared_with_the_state_when_it_was_taken() {
    // Moving at 1 m/s north: a fix 50 ms old says where the vehicle was
    // then. Compared with the present it would be a 5 cm error (25 σ).
    let mut f = Filter::new(EskfConfig::BMI088).unwrap();
    let est = StateEstimate {
        pos_ned_m: Vector3::zeros(),
        vel_ned_mps: Vector3::new(1.0, 0.0, 0.0),
        att: Vector4::new(1.0, 0.0, 0.0, 0.0),
        rates_frd_radps: Vector3::zeros(),
    };
    f.start_at(&est, 0.002, 0.001, 0.001).unwrap();
    let s = at_rest(&Vector4::new(1.0, 0.0, 0.0, 0.0), Vector3::zeros());
    for _ in 0..100 {
        f.predict(&s, DT).unwrap();
    }
    let now = f.estimate().unwrap().pos_ned_m;
    assert!((now[0] - 0.2).abs() < 1e-5);
    let fix = Fix {
        age_s: 0.05,
        ..mocap(Vector3::new(0.15, 0.0, 0.0), 0.0)
    };
    f.fuse(&fix).unwrap();
    assert_eq!(f.counters().pos_rejected, 0);
    assert!((f.estimate().unwrap().pos_ned_m[0] - 0.2).abs() < 1e-3);
    // Fused as if it were current, the same fix would have failed the gate.
    f.fuse(&mocap(Vector3::new(0.15, 0.0, 0.0), 0.0)).unwrap();
    assert_eq!(f.counters().pos_rejected, 1);
}

#[test]
fn settings_that_are_not_finite_and_positive_are_named() {
    let mut c = EskfConfig::BMI088;
    c.accel_noise = f32::NAN;
    assert_eq!(Filter::new(c).err(), Some(EstimatorError::Config("accel_noise")));
    c = EskfConfig::BMI088;
    c.align_samples = 0;
    assert_eq!(Filter::new(c).err(), Some(EstimatorError::Config("align_samples")));
    assert!(EstimatorError::Config("gate_sigma").to_string().contains("gate_sigma"));
}
