//! Simulated sensors, sampled from the true plant state: what a flight
//! controller really gets instead of its state.
//!
//! - **IMU** (body FRD, at [`IMU_PERIOD_S`], 1 kHz, whatever the
//!   controller's rate): gyro (rad/s) and accelerometer
//!   (specific force, m/s²), each with white noise from a datasheet noise
//!   density (per-sample σ = density·√rate), a bias (a constant offset drawn
//!   from the seed plus a random walk), range saturation, and a one-sample
//!   delay (sample k is delivered at k + 1, 1 ms later).
//! - **Fixes**, one of two profiles ([`FixProfile`]): `mocap` (position and
//!   heading) or `gps` (position and velocity, with a barometer and a
//!   magnetometer heading), each measured on a fixed period and delivered
//!   after its latency, stamped with its age.
//! - **Faults** on demand ([`Faults`]): a window without fixes, a 5 m
//!   outlier, a NaN or stuck IMU sample, accelerometer clipping.
//!
//! Everything is f64 and seeded: the same seed gives the same readings.

use crate::noise::SplitMix;
use crate::plant::Plant;
use anyhow::{bail, Result};
use fc_core::estimate::{Fix, ImuSample};
use fc_core::quat_to_euler;
use nalgebra::{Vector3, Vector4};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// The IMU's sample period, s (1 kHz: a BMI088's gyro and accelerometer
/// run at 1 kHz and more; the estimator steps at every sample).
pub const IMU_PERIOD_S: f64 = 0.001;

const DEG: f64 = std::f64::consts::PI / 180.0;
/// Standard gravity, m/s² (for g-denominated datasheet figures).
const G0: f64 = 9.80665;

/// Which slow sensors the vehicle has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum FixProfile {
    /// Motion capture: position at 100 Hz, σ 2 mm, 10 ms latency, with heading (σ 0.5°).
    Mocap,
    /// GNSS: 10 Hz, σ 0.3 m horizontal / 0.5 m vertical, velocity σ 0.05 m/s,
    /// 100 ms latency; a barometer (50 Hz, σ 0.1 m, slow drift) and a
    /// magnetometer heading (50 Hz, σ 1°).
    Gps,
}

impl FixProfile {
    /// Lower-case name (CLI, reports).
    pub fn name(self) -> &'static str {
        match self {
            FixProfile::Mocap => "mocap",
            FixProfile::Gps => "gps",
        }
    }

    /// The profile's numbers.
    pub fn model(self) -> FixModel {
        match self {
            FixProfile::Mocap => FixModel {
                period_s: 0.01,
                latency_s: 0.01,
                pos_sigma_h_m: 0.002,
                pos_sigma_v_m: 0.002,
                vel_sigma_mps: None,
                yaw_sigma_rad: Some(0.5 * DEG),
                baro: None,
                mag: None,
            },
            FixProfile::Gps => FixModel {
                period_s: 0.1,
                latency_s: 0.1,
                pos_sigma_h_m: 0.3,
                pos_sigma_v_m: 0.5,
                vel_sigma_mps: Some(0.05),
                yaw_sigma_rad: None,
                baro: Some(Baro {
                    period_s: 0.02,
                    sigma_m: 0.1,
                    drift_mpsqrts: 0.002,
                }),
                mag: Some(Mag {
                    period_s: 0.02,
                    sigma_rad: 1.0 * DEG,
                }),
            },
        }
    }
}

/// A barometer: altitude with white noise and a random-walk drift.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Baro {
    /// Sample period, s.
    pub period_s: f64,
    /// White noise, 1σ, m.
    pub sigma_m: f64,
    /// Drift (random walk), m/√s.
    pub drift_mpsqrts: f64,
}

/// A magnetometer reduced to the heading it gives.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Mag {
    /// Sample period, s.
    pub period_s: f64,
    /// Heading noise, 1σ, rad.
    pub sigma_rad: f64,
}

/// The position source's numbers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FixModel {
    /// Fix period, s.
    pub period_s: f64,
    /// Time from measurement to delivery, s.
    pub latency_s: f64,
    /// Horizontal position noise, 1σ, m.
    pub pos_sigma_h_m: f64,
    /// Vertical position noise, 1σ, m.
    pub pos_sigma_v_m: f64,
    /// Velocity noise, 1σ, m/s (`None`: no velocity).
    pub vel_sigma_mps: Option<f64>,
    /// Heading noise with the fix, 1σ, rad (`None`: no heading in the fix).
    pub yaw_sigma_rad: Option<f64>,
    /// A barometer beside the fix.
    pub baro: Option<Baro>,
    /// A magnetometer heading beside the fix.
    pub mag: Option<Mag>,
}

/// The IMU's numbers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ImuModel {
    /// Gyro white-noise density, rad/s/√Hz.
    pub gyro_noise: f64,
    /// Accelerometer white-noise density, m/s²/√Hz.
    pub accel_noise: f64,
    /// Gyro constant offset, 1σ per axis (drawn once per seed), rad/s.
    pub gyro_offset_sigma: f64,
    /// Accelerometer constant offset on body x and y, 1σ (the residual
    /// after a level calibration), m/s².
    pub accel_offset_sigma_xy: f64,
    /// Accelerometer constant offset on body z, 1σ, m/s².
    pub accel_offset_sigma_z: f64,
    /// Gyro bias random walk, rad/s/√s.
    pub gyro_bias_walk: f64,
    /// Accelerometer bias random walk, m/s²/√s.
    pub accel_bias_walk: f64,
    /// Gyro range (saturates), rad/s.
    pub gyro_range_radps: f64,
    /// Accelerometer range (clips), m/s².
    pub accel_range_mps2: f64,
}

impl ImuModel {
    /// Bosch BMI088 (the Crazyflie 2.1's IMU): gyro 0.014 °/s/√Hz, ±2000 °/s;
    /// accelerometer 175 µg/√Hz, ±24 g; offsets 0.5 °/s and 3 mg (x, y,
    /// after calibration) / 20 mg (z).
    pub const BMI088: ImuModel = ImuModel {
        gyro_noise: 0.014 * DEG,
        accel_noise: 175.0e-6 * G0,
        gyro_offset_sigma: 0.5 * DEG,
        accel_offset_sigma_xy: 3.0e-3 * G0,
        accel_offset_sigma_z: 20.0e-3 * G0,
        gyro_bias_walk: 2.0e-5,
        accel_bias_walk: 2.0e-4,
        gyro_range_radps: 2000.0 * DEG,
        accel_range_mps2: 24.0 * G0,
    };
}

/// Faults injected on demand (times in s of simulated time).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Faults {
    /// No position fix (nor the fix's heading) in `[start, start + length)`.
    pub outage: Option<(f64, f64)>,
    /// The first fix at or after this time is 5 m off (north).
    pub outlier_at_s: Option<f64>,
    /// The first IMU sample at or after this time is NaN.
    pub imu_nan_at_s: Option<f64>,
    /// The IMU repeats one sample over `[start, start + length)`.
    pub imu_stuck: Option<(f64, f64)>,
    /// Every IMU sample in `[start, start + length)` is NaN: a part that
    /// answers garbage, as long as it lasts.
    #[serde(default)]
    pub imu_dead: Option<(f64, f64)>,
    /// The first IMU sample at or after this time sees a 30 g shock on
    /// body z (it clips at the range).
    pub accel_clip_at_s: Option<f64>,
}

/// Everything that defines the simulated sensors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SensorConfig {
    /// Position source.
    pub profile: FixProfile,
    /// IMU.
    pub imu: ImuModel,
    /// Faults.
    pub faults: Faults,
    /// Seed of the noise (same seed, same readings).
    pub seed: u64,
}

impl SensorConfig {
    /// A BMI088 with the given position source, no faults.
    pub fn new(profile: FixProfile, seed: u64) -> Self {
        Self {
            profile,
            imu: ImuModel::BMI088,
            faults: Faults::default(),
            seed,
        }
    }
}

/// What the sensors deliver at one IMU step.
#[derive(Debug, Clone, PartialEq)]
pub struct Readings {
    /// The IMU sample (taken one step earlier).
    pub imu: ImuSample,
    /// Fixes arriving now, each stamped with its age.
    pub fixes: Vec<Fix>,
}

/// Gyro (rad/s) and accelerometer (m/s²) biases, FRD.
pub type Biases = (Vector3<f64>, Vector3<f64>);

/// The sensors of one flight.
#[derive(Debug, Clone)]
pub struct Sensors {
    cfg: SensorConfig,
    fix: FixModel,
    dt: f64,
    g: SplitMix,
    gyro_bias: Vector3<f64>,
    accel_bias: Vector3<f64>,
    baro_drift: f64,
    /// The sample taken at the previous step (delivered now) and the
    /// biases it was taken with.
    prev: Option<(ImuSample, Biases)>,
    /// The biases of the sample delivered last.
    delivered_bias: Biases,
    in_transit: VecDeque<(u64, Fix)>,
    step: u64,
    outlier_done: bool,
    nan_done: bool,
    clip_done: bool,
}

/// Whole steps of `dt` in `period`; `Err` unless it is one (±1e-9 s) and ≥ `min`.
fn steps_of(period: f64, dt: f64, what: &str, min: u64) -> Result<u64> {
    let n = (period / dt).round();
    if !(n >= min as f64 && (n * dt - period).abs() < 1e-9) {
        bail!("the {what} ({period} s) must be a whole number (≥ {min}) of IMU periods ({dt} s)");
    }
    Ok(n as u64)
}

impl Sensors {
    /// The sensors with the IMU sampled every `dt` s ([`IMU_PERIOD_S`] in
    /// flights). `Err` if a sensor's period or latency is not a whole number
    /// of IMU periods.
    pub fn new(cfg: SensorConfig, dt: f64) -> Result<Self> {
        let fix = cfg.profile.model();
        steps_of(fix.period_s, dt, "fix period", 1)?;
        steps_of(fix.latency_s, dt, "fix latency", 0)?;
        if let Some(b) = fix.baro {
            steps_of(b.period_s, dt, "barometer period", 1)?;
        }
        if let Some(m) = fix.mag {
            steps_of(m.period_s, dt, "magnetometer period", 1)?;
        }
        let mut g = SplitMix(cfg.seed ^ 0x5e_u64.rotate_left(56));
        let imu = cfg.imu;
        let mut draw3 = |sx: f64, sy: f64, sz: f64| Vector3::new(sx * g.normal(), sy * g.normal(), sz * g.normal());
        let gyro_bias = draw3(imu.gyro_offset_sigma, imu.gyro_offset_sigma, imu.gyro_offset_sigma);
        let accel_bias = draw3(
            imu.accel_offset_sigma_xy,
            imu.accel_offset_sigma_xy,
            imu.accel_offset_sigma_z,
        );
        Ok(Self {
            cfg,
            fix,
            dt,
            g,
            gyro_bias,
            accel_bias,
            baro_drift: 0.0,
            prev: None,
            delivered_bias: (gyro_bias, accel_bias),
            in_transit: VecDeque::new(),
            step: 0,
            outlier_done: false,
            nan_done: false,
            clip_done: false,
        })
    }

    /// The true gyro (rad/s) and accelerometer (m/s²) biases of the IMU
    /// sample delivered by the last [`Sensors::read`] (FRD).
    pub fn true_biases(&self) -> (Vector3<f64>, Vector3<f64>) {
        self.delivered_bias
    }

    fn noise3(&mut self, sigma: Vector3<f64>) -> Vector3<f64> {
        Vector3::new(
            sigma[0] * self.g.normal(),
            sigma[1] * self.g.normal(),
            sigma[2] * self.g.normal(),
        )
    }

    /// The readings of the IMU step at time `t` (s) of `plant`.
    pub fn read(&mut self, t: f64, plant: &Plant) -> Readings {
        let x = plant.quat_state();
        let bias_now = (self.gyro_bias, self.accel_bias);
        let now = (self.sample_imu(t, &x, plant), bias_now);
        let (imu, bias) = self.prev.replace(now).unwrap_or(now);
        self.delivered_bias = bias;
        let mut fixes = Vec::new();
        self.measure_fixes(t, &x);
        while self.in_transit.front().is_some_and(|(due, _)| *due <= self.step) {
            if let Some((_, f)) = self.in_transit.pop_front() {
                fixes.push(f);
            }
        }
        self.step += 1;
        Readings { imu, fixes }
    }

    fn sample_imu(&mut self, t: f64, x: &fc_core::QuatState<f64>, plant: &Plant) -> ImuSample {
        let m = self.cfg.imu;
        let rate = 1.0 / self.dt;
        let sg = m.gyro_noise * rate.sqrt();
        let sa = m.accel_noise * rate.sqrt();
        let w = Vector3::new(x[10], x[11], x[12]);
        let mut gyro = w + self.gyro_bias + self.noise3(Vector3::repeat(sg));
        let mut accel = plant.specific_force_frd() + self.accel_bias + self.noise3(Vector3::repeat(sa));
        // The biases walk.
        let sq = self.dt.sqrt();
        let walk_g = self.noise3(Vector3::repeat(m.gyro_bias_walk * sq));
        let walk_a = self.noise3(Vector3::repeat(m.accel_bias_walk * sq));
        self.gyro_bias += walk_g;
        self.accel_bias += walk_a;
        let f = &self.cfg.faults;
        if f.accel_clip_at_s.is_some_and(|at| t >= at) && !self.clip_done {
            self.clip_done = true;
            accel[2] -= 30.0 * G0;
        }
        gyro = gyro.map(|v| v.clamp(-m.gyro_range_radps, m.gyro_range_radps));
        accel = accel.map(|v| v.clamp(-m.accel_range_mps2, m.accel_range_mps2));
        let mut s = ImuSample {
            gyro_frd_radps: gyro.cast(),
            accel_frd_mps2: accel.cast(),
        };
        if f.imu_nan_at_s.is_some_and(|at| t >= at) && !self.nan_done {
            self.nan_done = true;
            s.gyro_frd_radps[0] = f32::NAN;
        }
        if f.imu_dead.is_some_and(|(start, len)| t >= start && t < start + len) {
            s.gyro_frd_radps = Vector3::repeat(f32::NAN);
            s.accel_frd_mps2 = Vector3::repeat(f32::NAN);
        }
        if let (Some((start, len)), Some((prev, _))) = (f.imu_stuck, self.prev) {
            if t >= start && t < start + len {
                s = prev;
            }
        }
        s
    }

    fn measure_fixes(&mut self, t: f64, x: &fc_core::QuatState<f64>) {
        let fm = self.fix;
        let dt = self.dt;
        let pos = Vector3::new(x[0], x[1], x[2]);
        let vel = Vector3::new(x[3], x[4], x[5]);
        let yaw = quat_to_euler(&Vector4::new(x[6], x[7], x[8], x[9]))[2];
        let every = |p: f64| (p / dt).round() as u64;
        let faults = self.cfg.faults;
        let in_outage = faults.outage.is_some_and(|(s, l)| t >= s && t < s + l);
        if self.step.is_multiple_of(every(fm.period_s)) && !in_outage {
            let sig = Vector3::new(fm.pos_sigma_h_m, fm.pos_sigma_h_m, fm.pos_sigma_v_m);
            let mut p = pos + self.noise3(sig);
            if faults.outlier_at_s.is_some_and(|at| t >= at) && !self.outlier_done {
                self.outlier_done = true;
                p[0] += 5.0;
            }
            let mut fix = Fix {
                age_s: fm.latency_s as f32,
                pos_ned_m: Some(p.cast()),
                pos_sigma_m: sig.cast(),
                ..Fix::EMPTY
            };
            if let Some(sv) = fm.vel_sigma_mps {
                fix.vel_ned_mps = Some((vel + self.noise3(Vector3::repeat(sv))).cast());
                fix.vel_sigma_mps = sv as f32;
            }
            if let Some(sy) = fm.yaw_sigma_rad {
                fix.yaw_rad = Some(fc_core::control::wrap_pi(yaw + sy * self.g.normal()) as f32);
                fix.yaw_sigma_rad = sy as f32;
            }
            let due = self.step + every(fm.latency_s);
            self.in_transit.push_back((due, fix));
        }
        let mut side = Fix::EMPTY;
        if let Some(b) = fm.baro {
            self.baro_drift += b.drift_mpsqrts * dt.sqrt() * self.g.normal();
            if self.step.is_multiple_of(every(b.period_s)) {
                side.alt_m = Some((-pos[2] + self.baro_drift + b.sigma_m * self.g.normal()) as f32);
                side.alt_sigma_m = b.sigma_m as f32;
            }
        }
        if let Some(m) = fm.mag {
            if self.step.is_multiple_of(every(m.period_s)) {
                side.yaw_rad = Some(fc_core::control::wrap_pi(yaw + m.sigma_rad * self.g.normal()) as f32);
                side.yaw_sigma_rad = m.sigma_rad as f32;
            }
        }
        if side.alt_m.is_some() || side.yaw_rad.is_some() {
            // Baro and magnetometer arrive at once (sorted before later fixes).
            let at = self.in_transit.partition_point(|(due, _)| *due <= self.step);
            self.in_transit.insert(at, (self.step, side));
        }
    }
}

/// Rotation vector (NED) taking `est` to `truth`: the attitude error as the
/// filter defines it (`q_true = exp(δθ) ⊗ q̂`), rad.
pub fn attitude_error(truth: &Vector4<f64>, est: &Vector4<f64>) -> Vector3<f64> {
    let dq = fc_core::quat_mul(truth, &fc_core::quat_conj(est));
    let s = if dq[0] < 0.0 { -1.0 } else { 1.0 };
    let v = Vector3::new(dq[1], dq[2], dq[3]) * s;
    let n = v.norm();
    if n < 1e-12 {
        return v * 2.0;
    }
    v * (2.0 * n.atan2(dq[0] * s) / n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plant::PlantConfig;
    use fc_core::{hover_quat_state, AttitudeForm};

    fn hover_plant() -> Plant {
        Plant::new(
            PlantConfig::nominal(AttitudeForm::Quaternion),
            &hover_quat_state(&Vector3::new(0.0, 0.0, -1.0), 0.3),
        )
    }

    #[test]
    fn a_hovering_imu_reads_minus_g_with_the_datasheet_spread() {
        let plant = hover_plant();
        let mut s = Sensors::new(SensorConfig::new(FixProfile::Mocap, 3), 0.002).unwrap();
        let n = 20_000;
        let (mut sum, mut sq) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
        for k in 0..n {
            let r = s.read(k as f64 * 0.002, &plant);
            let a: Vector3<f64> = r.imu.accel_frd_mps2.cast();
            sum += a;
            sq += a.component_mul(&a);
        }
        let mean = sum / n as f64;
        let sd = (sq / n as f64 - mean.component_mul(&mean)).map(f64::sqrt);
        let (_, ba) = s.true_biases();
        // Specific force in hover: (0, 0, −g) plus the bias.
        assert!((mean - Vector3::new(0.0, 0.0, -9.81) - ba).amax() < 0.01, "{mean:?}");
        // Per-sample σ = density·√rate = 1.716e-3·√500 = 0.0384 m/s².
        let want = ImuModel::BMI088.accel_noise * 500f64.sqrt();
        assert!(sd.iter().all(|v| (v / want - 1.0).abs() < 0.05), "{sd:?} vs {want}");
    }

    #[test]
    fn fixes_arrive_on_their_period_after_their_latency() {
        let plant = hover_plant();
        let mut s = Sensors::new(SensorConfig::new(FixProfile::Gps, 1), 0.002).unwrap();
        let mut pos_at = Vec::new();
        let mut alt = 0;
        for k in 0..500 {
            let r = s.read(k as f64 * 0.002, &plant);
            for f in r.fixes {
                if f.pos_ned_m.is_some() {
                    assert!((f.age_s - 0.1).abs() < 1e-6);
                    pos_at.push(k);
                }
                alt += usize::from(f.alt_m.is_some());
            }
        }
        // 10 Hz, first measured at step 0 and delivered 100 ms (50 steps) later.
        assert_eq!(pos_at[..3], [50, 100, 150]);
        assert_eq!(pos_at.len(), 9);
        assert_eq!(alt, 50, "50 Hz barometer over 1 s");
    }

    #[test]
    fn an_outage_delivers_no_fix_and_an_outlier_is_five_metres_off() {
        let plant = hover_plant();
        let mut cfg = SensorConfig::new(FixProfile::Mocap, 1);
        cfg.faults.outage = Some((0.1, 0.2));
        cfg.faults.outlier_at_s = Some(0.5);
        let mut s = Sensors::new(cfg, 0.002).unwrap();
        let mut got = Vec::new();
        for k in 0..400 {
            let t = k as f64 * 0.002;
            for f in s.read(t, &plant).fixes {
                got.push((t, f.pos_ned_m.unwrap()[0]));
            }
        }
        // Measured in [0.1, 0.3) → none delivered in [0.11, 0.31).
        assert!(got.iter().all(|(t, _)| !(0.111..0.309).contains(t)), "{got:?}");
        let off: Vec<_> = got.iter().filter(|(_, x)| x.abs() > 1.0).collect();
        assert_eq!(off.len(), 1);
        assert!((off[0].0 - 0.51).abs() < 1e-9 && (off[0].1 - 5.0).abs() < 0.01);
    }

    #[test]
    fn the_attitude_error_is_the_rotation_between_the_two() {
        let a = fc_core::euler_to_quat(0.1, 0.2, 0.3);
        let d = Vector3::new(0.01, -0.02, 0.03);
        let b = fc_core::quat_mul(&crate::sensors::tests::exp(&d), &a);
        assert!((attitude_error(&b, &a) - d).amax() < 1e-12);
    }

    fn exp(a: &Vector3<f64>) -> Vector4<f64> {
        let n = a.norm();
        let k = (0.5 * n).sin() / n;
        Vector4::new((0.5 * n).cos(), k * a[0], k * a[1], k * a[2])
    }
}
