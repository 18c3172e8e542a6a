//! On-board state estimation: what turns an IMU and a slower, delayed
//! position source into the [`StateEstimate`](crate::control::StateEstimate)
//! every controller reads.
//!
//! [`Eskf`] is an error-state (multiplicative) extended Kalman filter, the
//! structure of PX4's EKF2 and of most small-vehicle estimators:
//!
//! - **nominal state**: position and velocity (NED, m, m/s), attitude (unit
//!   quaternion body FRD → NED), gyro bias (FRD, rad/s), accelerometer bias
//!   (FRD, m/s²; its horizontal part is observable only as the vehicle
//!   turns, and the filter says so: its tilt σ stays at that bias' σ/g);
//! - **error state** (15): `[δp δv δθ δb_g δb_a]`, with the attitude error
//!   a small rotation vector in NED (`q_true = exp(δθ) ⊗ q̂`), so that the
//!   gyro and accelerometer noise are isotropic in it;
//! - **propagation** with every IMU sample (1 kHz in the SIL; specific
//!   force and body rates), the covariance through the sparse transition
//!   matrix (no dense 13×13 products);
//! - **updates** from [`Fix`]es (position, velocity, heading, barometric
//!   altitude) as sequential scalar updates, each fix gated on its
//!   normalised innovation, the measurement compared with the filter's
//!   state *at the time it was taken* (a bounded history of the nominal
//!   state, `H` entries: the "delayed-state innovation");
//! - **bad input** never enters: a non-finite or out-of-range IMU sample is
//!   counted and replaced by the last good one; a fix that fails its gate is
//!   counted and dropped; the covariance is kept symmetric with a positive
//!   diagonal and reset if it ever becomes non-finite.
//!
//! Derivation and the choices it makes: docs/book/src/model.md §11.

mod eskf;

pub use eskf::{Eskf, EskfCounters, Mode, TestRatios, ERR};

use nalgebra::Vector3;

/// One IMU sample, body FRD.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Body rates (p, q, r), rad/s.
    pub gyro_frd_radps: Vector3<f32>,
    /// Specific force (what an accelerometer measures: acceleration minus
    /// gravity, so `(0, 0, −g)` at rest and in hover), m/s².
    pub accel_frd_mps2: Vector3<f32>,
}

/// A measurement from the slow sensors, taken `age_s` before the IMU sample
/// it is fused with. Any part may be absent; sigmas are the sensor's 1σ.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fix {
    /// Latency: time from the measurement to the present step, s (≥ 0).
    pub age_s: f32,
    /// Position, NED, m.
    pub pos_ned_m: Option<Vector3<f32>>,
    /// 1σ of each position axis, m.
    pub pos_sigma_m: Vector3<f32>,
    /// Velocity, NED, m/s.
    pub vel_ned_mps: Option<Vector3<f32>>,
    /// 1σ of each velocity axis, m/s.
    pub vel_sigma_mps: f32,
    /// Heading ψ (ZYX yaw), rad.
    pub yaw_rad: Option<f32>,
    /// 1σ of the heading, rad.
    pub yaw_sigma_rad: f32,
    /// Barometric altitude (up, = −z NED plus the baro's own offset), m.
    pub alt_m: Option<f32>,
    /// 1σ of the altitude, m.
    pub alt_sigma_m: f32,
}

impl Fix {
    /// A fix with nothing in it (fill the parts you have).
    pub const EMPTY: Fix = Fix {
        age_s: 0.0,
        pos_ned_m: None,
        pos_sigma_m: Vector3::new(1.0, 1.0, 1.0),
        vel_ned_mps: None,
        vel_sigma_mps: 1.0,
        yaw_rad: None,
        yaw_sigma_rad: 1.0,
        alt_m: None,
        alt_sigma_m: 1.0,
    };
}

/// What the filter assumes of its sensors and how cautious it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EskfConfig {
    /// Gyro white-noise density, rad/s/√Hz.
    pub gyro_noise: f32,
    /// Accelerometer white-noise density, m/s²/√Hz.
    pub accel_noise: f32,
    /// Gyro bias random walk, rad/s/√s.
    pub gyro_bias_walk: f32,
    /// Accelerometer bias random walk, m/s²/√s.
    pub accel_bias_walk: f32,
    /// Gyro range: a sample beyond it (any axis) is out of range, rad/s.
    pub gyro_range_radps: f32,
    /// Accelerometer range: a sample within 0.1 % of it (any axis) has
    /// clipped (a saturated sensor reads its full scale), m/s².
    pub accel_range_mps2: f32,
    /// Innovation gate: a fix whose normalised innovation exceeds this
    /// many σ (per scalar; the position triple jointly) is rejected.
    pub gate_sigma: f32,
    /// Consecutive rejected position fixes after which the filter believes
    /// the fix and resets its position and velocity to it (a real jump, or
    /// a filter that has drifted away), counted.
    pub reset_after_rejections: u16,
    /// IMU samples averaged for the initial alignment (vehicle at rest).
    pub align_samples: u16,
    /// 1σ of the initial attitude after alignment, rad.
    pub init_att_sigma_rad: f32,
    /// 1σ of the initial velocity, m/s.
    pub init_vel_sigma_mps: f32,
    /// 1σ of the initial gyro bias, rad/s.
    pub init_gyro_bias_sigma: f32,
    /// 1σ of the initial accelerometer bias on body x and y (the residual
    /// after a level calibration), m/s².
    pub init_accel_bias_sigma_xy: f32,
    /// 1σ of the initial accelerometer bias on body z, m/s².
    pub init_accel_bias_sigma_z: f32,
    /// Gravity, m/s².
    pub gravity_mps2: f32,
}

impl EskfConfig {
    /// The Bosch BMI088 (the Crazyflie 2.1's IMU) at its datasheet noise:
    /// gyro 0.014 °/s/√Hz, accelerometer 175 µg/√Hz, ±2000 °/s, ±24 g.
    pub const BMI088: EskfConfig = EskfConfig {
        gyro_noise: 0.014 * core::f32::consts::PI / 180.0,
        accel_noise: 175.0e-6 * 9.81,
        gyro_bias_walk: 2.0e-5,
        accel_bias_walk: 2.0e-4,
        gyro_range_radps: 2000.0 * core::f32::consts::PI / 180.0,
        accel_range_mps2: 24.0 * 9.80665,
        gate_sigma: 5.0,
        reset_after_rejections: 20,
        align_samples: 25,
        init_att_sigma_rad: 0.02,
        init_vel_sigma_mps: 0.1,
        init_gyro_bias_sigma: 0.01,
        init_accel_bias_sigma_xy: 0.03,
        init_accel_bias_sigma_z: 0.2,
        gravity_mps2: 9.81,
    };

    /// `Err` naming the first value that is not finite and positive.
    pub fn check(&self) -> Result<(), EstimatorError> {
        let fields = [
            ("gyro_noise", self.gyro_noise),
            ("accel_noise", self.accel_noise),
            ("gyro_bias_walk", self.gyro_bias_walk),
            ("accel_bias_walk", self.accel_bias_walk),
            ("gyro_range_radps", self.gyro_range_radps),
            ("accel_range_mps2", self.accel_range_mps2),
            ("gate_sigma", self.gate_sigma),
            ("init_att_sigma_rad", self.init_att_sigma_rad),
            ("init_vel_sigma_mps", self.init_vel_sigma_mps),
            ("init_gyro_bias_sigma", self.init_gyro_bias_sigma),
            ("init_accel_bias_sigma_xy", self.init_accel_bias_sigma_xy),
            ("init_accel_bias_sigma_z", self.init_accel_bias_sigma_z),
            ("gravity_mps2", self.gravity_mps2),
        ];
        check_positive(&fields)?;
        if self.align_samples == 0 {
            return Err(EstimatorError::Config("align_samples"));
        }
        Ok(())
    }
}

/// `Err` naming the first setting that is not finite and positive.
pub fn check_positive(fields: &[(&'static str, f32)]) -> Result<(), EstimatorError> {
    match fields.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        Some((name, _)) => Err(EstimatorError::Config(name)),
        None => Ok(()),
    }
}

/// Why the filter refused a call.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EstimatorError {
    /// A configuration value is not finite and positive (its name).
    Config(&'static str),
    /// The step length is not finite or outside (0, 0.1] s.
    Step,
    /// Not aligned yet: no estimate to give.
    NotAligned,
    /// A fix's age is negative, non-finite or older than the history.
    FixAge,
    /// A sigma of a fix is not finite and positive.
    FixSigma,
    /// A value of a fix is not finite.
    FixValue,
    /// The initial state given to [`Eskf::start_at`] is not finite.
    Initial,
}

impl core::fmt::Display for EstimatorError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EstimatorError::Config(name) => write!(f, "estimator setting {name} must be finite and positive"),
            EstimatorError::Step => write!(f, "estimator step must be finite and in (0, 0.1] s"),
            EstimatorError::NotAligned => write!(f, "the estimator is not aligned yet"),
            EstimatorError::FixAge => {
                write!(f, "fix age must be finite, ≥ 0 and within the estimator's history")
            }
            EstimatorError::FixSigma => write!(f, "a fix's sigma must be finite and positive"),
            EstimatorError::FixValue => write!(f, "a fix's value must be finite"),
            EstimatorError::Initial => write!(f, "the initial state must be finite with a unit attitude"),
        }
    }
}

#[cfg(test)]
mod tests;
