//! The supervisor of a vehicle that flies from its own board's sensors
//! (the Crazyflie's `supervisor.c`; [`Supervisor`], which the CRTP vehicle,
//! `fc_crtp::vehicle`, steps after its estimator; PX4's HIL samples come
//! checked by the simulator, and PX4's modes have their lockdown,
//! [`crate::modes`]): whether the board's sensors started, whether the
//! battery is above its floor, every IMU sample, tumble, and the end of a
//! landing. What passes goes to the motors through [`crate::power`].
//!
//! - **Arming** is refused while a sensor the board reported down
//!   ([`SensorDown`]) or the battery is below [`BATTERY_FLOOR_V`], as well
//!   as for the vehicle's own reasons (aligning, tumbled, locked;
//!   [`crate::arming`]).
//! - **Tumble**: a vehicle flying a set-point tilted beyond
//!   [`TUMBLE_TILT_RAD`] ([`tumbled`]) stops its motors, and arming is
//!   refused until a recovery ([`Arming::tumble`]).
//! - **Every IMU sample** goes through an [`ImuGuard`]: a sample the board
//!   could not read (`None`: a bus error, a frozen part) or one that is not
//!   finite or beyond any MEMS IMU's range is not flown; the last good one
//!   is, for at most [`IMU_TIMEOUT_US`]. Past that, an armed vehicle in
//!   flight starts a failsafe descent (straight down at
//!   [`FAILSAFE_DESCENT_MPS`] to the ground, then motors off), which good
//!   samples coming back do not cancel: a client takes over with a new
//!   command. Each kind is counted ([`ImuCounters`]).
//! - **A landing** (a landing segment, the failsafe descent) that has
//!   ended on its goal's ground ([`Commander::landed`]) stops the motors.
//!
//! A data-ready line that stops altogether runs no step at all: on the
//! Crazyflie 2.1 image the IWDG, fed only while samples are stepped, resets
//! the chip (`fc_stm32f405::watchdog`), which stops the motors.

use crate::arming::Arming;
use crate::commander::Commander;
use fc_core::control::StateEstimate;
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

/// The supervisor's gate: the motors turn, armed (`arming`) and flying a
/// set-point (the `commander` not idle), as a Crazyflie's do.
#[inline]
pub fn flying(arming: &Arming, commander: &Commander) -> bool {
    arming.armed() && !commander.is_idle()
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

/// What the supervisor did in one step ([`Supervisor::step`]), for the
/// vehicle to say.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Supervised {
    /// The IMU went silent in flight: a failsafe descent began.
    pub descent_began: bool,
    /// Tumbled: the motors stopped (still armed), arming refused until a
    /// recovery.
    pub tumbled: bool,
    /// A landing ended on the ground: the motors stopped.
    pub landed: bool,
}

/// The supervisor of a vehicle on its own board's sensors (the
/// Crazyflie's `supervisor.c`; see the module's documentation): the IMU's
/// samples checked, and each step's failsafe descent, tumble and end of a
/// landing, on the one arming state ([`Arming`]) and the commander
/// ([`Commander`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Supervisor {
    imu: ImuGuard,
    /// A failsafe descent began in this silence of the IMU.
    descending: bool,
}

impl Supervisor {
    /// No sample seen, no failsafe.
    pub const fn new() -> Self {
        Self {
            imu: ImuGuard::new(),
            descending: false,
        }
    }

    /// The sample to step at `t_us` ([`ImuGuard::take`]).
    pub fn take(&mut self, t_us: u64, s: Option<&ImuSample>) -> (Option<ImuSample>, ImuOutcome) {
        self.imu.take(t_us, s)
    }

    /// A new time line (a host that started again, [`ImuGuard::restart`]).
    pub fn restart(&mut self) {
        self.imu.restart();
    }

    /// The IMU samples that were not good, by kind.
    pub fn imu_counters(&self) -> ImuCounters {
        self.imu.counters()
    }

    /// A failsafe descent is under way (the IMU went silent in flight).
    pub fn failsafe(&self) -> bool {
        self.descending
    }

    /// The checks of the step at `t_us`, after its estimator (`est`: its
    /// estimate, if any): a silent IMU in flight sends the `commander`
    /// straight down from where it flies (every command but a landing
    /// overruled), a tumble stops it and latches on `arming`, a landing
    /// that ended on its ground stops it. `memory`: what a trajectory flown
    /// is evaluated from ([`Commander::reference`]).
    pub fn step(
        &mut self,
        t_us: u64,
        arming: &mut Arming,
        commander: &mut Commander,
        est: Option<&StateEstimate<f32>>,
        memory: &impl crate::trajectory::Trajectories,
    ) -> Supervised {
        let mut done = Supervised::default();
        if !self.imu.silent() {
            self.descending = false;
        } else if flying(arming, commander) && !commander.is_landing() {
            done.descent_began = !self.descending;
            self.descending = true;
            let here = commander.reference(t_us, est, memory);
            commander.descend(&here, t_us, FAILSAFE_DESCENT_MPS);
        }
        let Some(est) = est else {
            return done;
        };
        if flying(arming, commander) && tumbled(&est.att) {
            arming.tumble();
            commander.stop();
            done.tumbled = true;
        }
        done.landed = commander.landed(t_us, est);
        done
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::NoTrajectories;
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

    fn at(down_m: f32, att: Vector4<f32>) -> StateEstimate<f32> {
        StateEstimate {
            pos_ned_m: Vector3::new(1.0, 2.0, down_m),
            vel_ned_mps: Vector3::zeros(),
            att,
            rates_frd_radps: Vector3::zeros(),
        }
    }

    const LEVEL: Vector4<f32> = Vector4::new(1.0, 0.0, 0.0, 0.0);

    /// An armed vehicle holding 2 m up.
    fn flying() -> (Arming, Commander) {
        let mut arming = Arming::new();
        let ready = crate::arming::ArmingState {
            sensor_down: None,
            battery_v: None,
            battery_floor_v: 0.0,
            nav: crate::nav::NavMode::Navigating,
            started: true,
        };
        arming.arm(&ready, || Ok(())).unwrap();
        let mut c = Commander::new();
        c.hold(fc_core::control::Setpoint::hold(Vector3::new(1.0, 2.0, -2.0), 0.0));
        (arming, c)
    }

    /// A silent IMU in flight starts one descent, straight down from where
    /// it flies at the failsafe rate, which good samples do not cancel;
    /// it ends on the ground with the motors stopped.
    #[test]
    fn a_silent_imu_in_flight_descends_to_the_ground_and_stops() {
        let (mut arming, mut c) = flying();
        let mut sup = Supervisor::new();
        let up = at(-2.0, LEVEL);
        sup.take(0, Some(&sample(0.0)));
        assert_eq!(
            sup.step(0, &mut arming, &mut c, Some(&up), &NoTrajectories),
            Supervised::default()
        );
        sup.take(IMU_TIMEOUT_US + 1, None);
        let s = sup.step(IMU_TIMEOUT_US + 1, &mut arming, &mut c, Some(&up), &NoTrajectories);
        assert!(s.descent_began && sup.failsafe() && c.is_landing());
        let seg = *c.segment().unwrap();
        assert_eq!(
            seg.goal().pos_ned_m,
            Vector3::new(1.0, 2.0, 0.0),
            "straight down to z = 0"
        );
        // Said once: the next silent step carries on.
        sup.take(IMU_TIMEOUT_US + 2, None);
        assert!(
            !sup.step(IMU_TIMEOUT_US + 2, &mut arming, &mut c, Some(&up), &NoTrajectories)
                .descent_began
        );
        // Good samples back: the failsafe is over, the descent is not.
        sup.take(IMU_TIMEOUT_US + 3, Some(&sample(0.0)));
        sup.step(IMU_TIMEOUT_US + 3, &mut arming, &mut c, Some(&up), &NoTrajectories);
        assert!(!sup.failsafe() && c.is_landing());
        // 2 m at 0.3 m/s: not landed before its end, landed on the ground after it.
        let end = IMU_TIMEOUT_US + 1 + (2.0 / FAILSAFE_DESCENT_MPS * 1e6) as u64;
        let ground = at(0.0, LEVEL);
        assert!(
            !sup.step(end - 100_000, &mut arming, &mut c, Some(&ground), &NoTrajectories)
                .landed
        );
        assert!(
            sup.step(end + 1, &mut arming, &mut c, Some(&ground), &NoTrajectories)
                .landed
        );
        assert!(c.is_idle() && arming.armed(), "motors stopped, still armed");
    }

    /// A tumble in flight stops the motors and latches, armed still; on
    /// the ground (nothing flown) a tilt is no tumble.
    #[test]
    fn a_tumble_in_flight_stops_and_latches() {
        let h = 61f32.to_radians() / 2.0;
        let tilted = at(-2.0, Vector4::new(h.cos(), h.sin(), 0.0, 0.0));
        let (mut arming, mut c) = flying();
        let mut sup = Supervisor::new();
        sup.take(0, Some(&sample(0.0)));
        let s = sup.step(0, &mut arming, &mut c, Some(&tilted), &NoTrajectories);
        assert_eq!(
            s,
            Supervised {
                tumbled: true,
                ..Supervised::default()
            }
        );
        assert!(c.is_idle() && arming.armed() && arming.tumbled());
        let mut on_ground = Arming::new();
        let mut idle = Commander::new();
        assert_eq!(
            sup.step(1, &mut on_ground, &mut idle, Some(&tilted), &NoTrajectories),
            Supervised::default()
        );
        assert!(!on_ground.tumbled());
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
