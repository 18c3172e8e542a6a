//! The supervisor's checks of a vehicle that flies from its own board's
//! sensors (the Crazyflie's `supervisor.c`; the CRTP vehicle,
//! `fc_crtp::vehicle`, runs them; PX4's HIL samples come checked by the
//! simulator): whether the board's sensors started, whether the battery is
//! above its floor, every IMU sample, and tumble. What passes goes to the
//! motors through [`crate::power`].
//!
//! - **Arming** is refused while a sensor the board reported down
//!   ([`SensorDown`]) or the battery is below [`BATTERY_FLOOR_V`], as well
//!   as for the vehicle's own reasons (aligning, tumbled, locked;
//!   [`crate::arming`]).
//! - **Tumble**: an armed vehicle tilted beyond [`TUMBLE_TILT_RAD`]
//!   ([`tumbled`]) stops its motors.
//! - **Every IMU sample** goes through an [`ImuGuard`]: a sample the board
//!   could not read (`None`: a bus error, a frozen part) or one that is not
//!   finite or beyond any MEMS IMU's range is not flown; the last good one
//!   is, for at most [`IMU_TIMEOUT_US`]. Past that, an armed vehicle in
//!   flight starts a failsafe descent (straight down at
//!   [`FAILSAFE_DESCENT_MPS`] to the ground, then motors off), which good
//!   samples coming back do not cancel: a client takes over with a new
//!   command. Each kind is counted ([`ImuCounters`]).
//!
//! A data-ready line that stops altogether runs no step at all: on the
//! Crazyflie 2.1 image the IWDG, fed only while samples are stepped, resets
//! the chip (`fc_stm32f405::watchdog`), which stops the motors.

use fc_core::estimate::ImuSample;

/// Longest gap between good IMU samples that is flown on the last good
/// one, µs (ten samples at 1 kHz).
pub const IMU_TIMEOUT_US: u64 = 10_000;
/// Lowest battery voltage to arm at, V (a 1S LiPo; the Crazyflie's
/// `LOW_VOLTAGE`).
pub const BATTERY_FLOOR_V: f32 = 3.2;
/// A rate beyond this is not a reading, rad/s (the BMI088's range is
/// ±2000 °/s = 34.9 rad/s; ICM-42688 and MPU-6000 share it).
pub const GYRO_LIMIT_RADPS: f32 = 40.0;
/// A specific force beyond this is not a reading, m/s² (the BMI088's
/// range is ±24 g = 235 m/s²).
pub const ACCEL_LIMIT_MPS2: f32 = 300.0;
/// The failsafe descent's rate, m/s.
pub const FAILSAFE_DESCENT_MPS: f32 = 0.3;
/// Tilt beyond which an armed vehicle is tumbled: motors off, rad (60°).
pub const TUMBLE_TILT_RAD: f32 = core::f32::consts::FRAC_PI_3;
/// cos([`TUMBLE_TILT_RAD`]): the supervisor compares the body z axis' down
/// component with it every step, so it is not computed there (libm's
/// `cosf` works in f64, which the Cortex-M4 has no unit for: ≈ 1 000
/// instructions a step).
pub const COS_TUMBLE_TILT: f32 = 0.5;

/// The attitude `q` (body FRD → NED, scalar first) tilted beyond
/// [`TUMBLE_TILT_RAD`]: its body z axis' down component, cos(tilt), below
/// [`COS_TUMBLE_TILT`].
#[inline]
pub fn tumbled(q: &fc_core::model::Quat<f32>) -> bool {
    let cos_tilt = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]);
    cos_tilt < COS_TUMBLE_TILT
}

/// A sensor the board could not start, as the vehicle's console and its
/// arming refusal name it (the driver's full error goes to the board's log).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SensorDown {
    /// The part ("BMI088 gyroscope").
    pub device: &'static str,
    /// What went wrong ("wrong chip id").
    pub why: &'static str,
}

impl core::fmt::Display for SensorDown {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "{}: {}", self.device, self.why)
    }
}

/// What became of one IMU sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ImuOutcome {
    /// Finite and within range: flown.
    Good,
    /// The board had none (its driver failed).
    Missing,
    /// Not finite, or beyond [`GYRO_LIMIT_RADPS`] / [`ACCEL_LIMIT_MPS2`].
    Bad,
}

/// Counts of the IMU samples that were not good, by kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImuCounters {
    /// Samples the board did not have.
    pub missing: u32,
    /// Samples refused as not finite or out of range.
    pub bad: u32,
    /// Steps flown on a held sample.
    pub held: u32,
    /// Times the IMU was silent past [`IMU_TIMEOUT_US`].
    pub timeouts: u32,
}

/// The IMU's samples checked, the last good one held.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuGuard {
    held: Option<ImuSample>,
    last_good_us: Option<u64>,
    silent: bool,
    counters: ImuCounters,
}

impl Default for ImuGuard {
    fn default() -> Self {
        Self::new()
    }
}

impl ImuGuard {
    /// No sample seen yet.
    pub const fn new() -> Self {
        Self {
            held: None,
            last_good_us: None,
            silent: false,
            counters: ImuCounters {
                missing: 0,
                bad: 0,
                held: 0,
                timeouts: 0,
            },
        }
    }

    /// Whether `s` is a reading: finite and within range.
    pub fn outcome(s: Option<&ImuSample>) -> ImuOutcome {
        let Some(s) = s else {
            return ImuOutcome::Missing;
        };
        let within = |v: &nalgebra::Vector3<f32>, limit: f32| v.iter().all(|x| x.is_finite() && x.abs() <= limit);
        if within(&s.gyro_frd_radps, GYRO_LIMIT_RADPS) && within(&s.accel_frd_mps2, ACCEL_LIMIT_MPS2) {
            ImuOutcome::Good
        } else {
            ImuOutcome::Bad
        }
    }

    /// The sample to step at `t_us` and what became of `s`: `s` if it is
    /// good, else the last good one, however old (it is all there is;
    /// [`ImuGuard::silent`] says when it is older than [`IMU_TIMEOUT_US`]).
    /// `None` before the first good sample.
    pub fn take(&mut self, t_us: u64, s: Option<&ImuSample>) -> (Option<ImuSample>, ImuOutcome) {
        let outcome = Self::outcome(s);
        match (outcome, s) {
            (ImuOutcome::Good, Some(s)) => {
                self.held = Some(*s);
                self.last_good_us = Some(t_us);
                self.silent = false;
            }
            (ImuOutcome::Missing, _) => self.counters.missing = self.counters.missing.saturating_add(1),
            _ => self.counters.bad = self.counters.bad.saturating_add(1),
        }
        if outcome != ImuOutcome::Good && self.held.is_some() {
            self.counters.held = self.counters.held.saturating_add(1);
        }
        let silent = self
            .last_good_us
            .is_some_and(|g| t_us.saturating_sub(g) > IMU_TIMEOUT_US);
        if silent && !self.silent {
            self.counters.timeouts = self.counters.timeouts.saturating_add(1);
        }
        self.silent = silent;
        (self.held, outcome)
    }

    /// No good sample for more than [`IMU_TIMEOUT_US`] at the last
    /// [`ImuGuard::take`].
    pub fn silent(&self) -> bool {
        self.silent
    }

    /// The counters.
    pub fn counters(&self) -> ImuCounters {
        self.counters
    }

    /// A new time line (a host that started again): the held sample and
    /// its time are forgotten; the counters stay.
    pub fn restart(&mut self) {
        self.held = None;
        self.last_good_us = None;
        self.silent = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector3, Vector4};

    /// The tumble threshold, held as a cosine, is the cosine of its angle
    /// (60°).
    #[test]
    fn the_tumble_cosine_is_the_tumble_angles() {
        let exact = f64::from(TUMBLE_TILT_RAD).cos();
        assert!((f64::from(COS_TUMBLE_TILT) - exact).abs() < 1e-7, "{exact}");
    }

    /// Tilted about any horizontal axis (a rotation by `tilt` about
    /// (cos a, sin a, 0): q = [cos(tilt/2), sin(tilt/2) cos a, sin(tilt/2)
    /// sin a, 0]), a vehicle is tumbled beyond 60°, whatever its heading.
    #[test]
    fn tumbled_beyond_sixty_degrees_about_any_axis() {
        for deg in [0.0f32, 30.0, 59.0, 61.0, 90.0, 180.0] {
            for a in [0.0f32, 0.7, 2.0, 4.0] {
                let h = deg.to_radians() / 2.0;
                let q = Vector4::new(h.cos(), h.sin() * a.cos(), h.sin() * a.sin(), 0.0);
                assert_eq!(tumbled(&q), deg > 60.0, "{deg}° about {a} rad");
                // A heading (about z) changes nothing.
                let yawed = Vector4::new(
                    q[0] * 0.6 - q[3] * 0.8,
                    q[1] * 0.6 - q[2] * 0.8,
                    q[2] * 0.6 + q[1] * 0.8,
                    q[3] * 0.6 + q[0] * 0.8,
                );
                assert_eq!(tumbled(&yawed), deg > 60.0, "{deg}° about {a} rad, yawed");
            }
        }
    }

    fn sample(gx: f32) -> ImuSample {
        ImuSample {
            gyro_frd_radps: Vector3::new(gx, 0.0, 0.0),
            accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
        }
    }

    #[test]
    fn bad_or_missing_samples_fly_the_last_good_one_and_ten_ms_of_them_is_a_timeout() {
        let mut g = ImuGuard::new();
        // Nothing good yet: nothing to fly.
        assert_eq!(g.take(0, None), (None, ImuOutcome::Missing));
        assert_eq!(g.take(1000, Some(&sample(0.1))), (Some(sample(0.1)), ImuOutcome::Good));
        // NaN, beyond range, missing: each flies 0.1.
        let nan = sample(f32::NAN);
        let wild = sample(GYRO_LIMIT_RADPS * 1.01);
        let mut wild_accel = sample(0.0);
        wild_accel.accel_frd_mps2[1] = -ACCEL_LIMIT_MPS2 * 1.01;
        for (k, s) in [Some(&nan), Some(&wild), None, Some(&wild_accel)]
            .into_iter()
            .enumerate()
        {
            let (flown, _) = g.take(2000 + 1000 * k as u64, s);
            assert_eq!(flown, Some(sample(0.1)));
            assert!(!g.silent());
        }
        // 10 ms after the last good one (at 1 ms): not yet silent; 11 ms: silent, once.
        g.take(11_000, None);
        assert!(!g.silent());
        g.take(11_001, None);
        assert!(g.silent());
        g.take(12_000, Some(&nan));
        assert!(g.silent());
        assert_eq!(
            g.counters(),
            ImuCounters {
                missing: 4,
                bad: 4,
                // The first missing sample had nothing to hold.
                held: 7,
                timeouts: 1
            }
        );
        // A good sample ends it; the next silence counts again.
        g.take(13_000, Some(&sample(0.2)));
        assert!(!g.silent());
        g.take(23_001, None);
        assert_eq!(g.counters().timeouts, 2);
        // The range limits hold exactly at the limit.
        assert_eq!(ImuGuard::outcome(Some(&sample(-GYRO_LIMIT_RADPS))), ImuOutcome::Good);
        g.restart();
        assert_eq!(g.take(0, None).0, None);
    }

    #[test]
    fn a_sensor_down_names_its_part_and_what_went_wrong() {
        let s = SensorDown {
            device: "BMI088 gyroscope",
            why: "wrong chip id",
        };
        assert_eq!(s.to_string(), "BMI088 gyroscope: wrong chip id");
    }
}
