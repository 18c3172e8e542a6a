//! Sensor noise: what the controllers see is the true state plus seeded,
//! white Gaussian errors on position (NED, m), velocity (NED, m/s), attitude
//! (a small body-frame rotation, rad) and body rates (FRD, rad/s), drawn
//! afresh at every control step. The plant, the metrics and the figures keep
//! the true state.
//!
//! White noise at the control rate is harsher than a real estimator's output
//! (which is low-passed and correlated): a conservative test of anything
//! that differentiates the state, such as the MPC's disturbance trend.

use anyhow::{bail, Result};
use fc_core::QuatState;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// splitmix64: a small, well-known generator; enough for reproducible draws.
#[derive(Debug, Clone)]
pub struct SplitMix(pub u64);

impl SplitMix {
    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi].
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }

    /// Standard normal (Box–Muller; one of the pair is used).
    pub fn normal(&mut self) -> f64 {
        // u1 in (0, 1]: ln never sees 0.
        let u1 = 1.0 - self.uniform(0.0, 1.0);
        let u2 = self.uniform(0.0, 1.0);
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// Standard deviations of the sensor errors, per axis, and the seed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SensorNoise {
    /// Position, NED, m.
    pub pos_m: f64,
    /// Velocity, NED, m/s.
    pub vel_mps: f64,
    /// Attitude: each component of a small body-frame rotation vector, rad.
    pub att_rad: f64,
    /// Body rates, FRD, rad/s.
    pub rate_radps: f64,
    /// Seed of the generator (same seed, same noise).
    pub seed: u64,
}

impl SensorNoise {
    /// A small quadrotor's fused estimate, as white noise: 5 mm, 2 cm/s,
    /// 0.3° and 0.6°/s (1 σ), scaled by `scale`.
    pub fn typical(scale: f64, seed: u64) -> Result<Self> {
        if !scale.is_finite() || scale < 0.0 {
            bail!("noise scale must be a finite number ≥ 0, got {scale}");
        }
        Ok(Self {
            pos_m: 0.005 * scale,
            vel_mps: 0.02 * scale,
            att_rad: 0.005 * scale,
            rate_radps: 0.01 * scale,
            seed,
        })
    }

    /// A generator of measurements with these errors.
    pub fn source(&self) -> NoiseSource {
        NoiseSource {
            spec: *self,
            g: SplitMix(self.seed),
        }
    }
}

/// Draws the noisy measurement of a state, one control step at a time.
#[derive(Debug, Clone)]
pub struct NoiseSource {
    spec: SensorNoise,
    g: SplitMix,
}

impl NoiseSource {
    fn vec3(&mut self, sigma: f64) -> Vector3<f64> {
        Vector3::new(
            sigma * self.g.normal(),
            sigma * self.g.normal(),
            sigma * self.g.normal(),
        )
    }

    /// The measured quaternion-form state `[x y z ẋ ẏ ż q0 q1 q2 q3 p q r]`:
    /// the true one with fresh errors; the quaternion stays a unit quaternion.
    pub fn measure(&mut self, x: &QuatState<f64>) -> QuatState<f64> {
        let s = self.spec;
        let mut m = *x;
        let dp = self.vec3(s.pos_m);
        let dv = self.vec3(s.vel_mps);
        let da = self.vec3(s.att_rad);
        let dw = self.vec3(s.rate_radps);
        for i in 0..3 {
            m[i] += dp[i];
            m[3 + i] += dv[i];
            m[10 + i] += dw[i];
        }
        let q = UnitQuaternion::from_quaternion(Quaternion::new(x[6], x[7], x[8], x[9]));
        let qm = q * UnitQuaternion::from_scaled_axis(da);
        m[6] = qm.w;
        m[7] = qm.i;
        m[8] = qm.j;
        m[9] = qm.k;
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_have_the_stated_spread_and_the_attitude_stays_unit() {
        let spec = SensorNoise::typical(2.0, 7).unwrap();
        let mut src = spec.source();
        let mut x = QuatState::<f64>::zeros();
        x[2] = -1.0;
        let q = UnitQuaternion::from_euler_angles(0.1, -0.2, 0.7);
        x[6] = q.w;
        x[7] = q.i;
        x[8] = q.j;
        x[9] = q.k;
        let n = 20_000;
        let (mut sp, mut sv, mut sa, mut sw, mut mean_p) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for _ in 0..n {
            let m = src.measure(&x);
            let qm = UnitQuaternion::from_quaternion(Quaternion::new(m[6], m[7], m[8], m[9]));
            assert!((Quaternion::new(m[6], m[7], m[8], m[9]).norm() - 1.0).abs() < 1e-12);
            // The error rotation, in the body frame.
            let e = (q.inverse() * qm).scaled_axis();
            sp += (m[0] - x[0]).powi(2);
            mean_p += m[1] - x[1];
            sv += (m[4] - x[4]).powi(2);
            sa += e[2].powi(2);
            sw += (m[12] - x[12]).powi(2);
        }
        let sd = |s: f64| (s / n as f64).sqrt();
        // 20 000 draws: the sample σ is within ≈ 1 % (1 σ) of the true one.
        for (got, want) in [
            (sd(sp), spec.pos_m),
            (sd(sv), spec.vel_mps),
            (sd(sa), spec.att_rad),
            (sd(sw), spec.rate_radps),
        ] {
            assert!((got / want - 1.0).abs() < 0.04, "σ {got} vs {want}");
        }
        assert!((mean_p / n as f64).abs() < 4.0 * spec.pos_m / (n as f64).sqrt());
    }

    #[test]
    fn the_same_seed_gives_the_same_noise() {
        let spec = SensorNoise::typical(1.0, 3).unwrap();
        let x = {
            let mut x = QuatState::<f64>::zeros();
            x[6] = 1.0;
            x
        };
        let (mut a, mut b) = (spec.source(), spec.source());
        let mut c = SensorNoise { seed: 4, ..spec }.source();
        let (ma, mb, mc) = (a.measure(&x), b.measure(&x), c.measure(&x));
        assert_eq!(ma, mb);
        assert_ne!(ma, mc);
        assert!(SensorNoise::typical(-1.0, 0).is_err() && SensorNoise::typical(f64::NAN, 0).is_err());
    }
}
