//! The supervisor, after the Crazyflie firmware's (`supervisor.c`): whether
//! the vehicle can fly, whether it has tumbled, and what to do when a
//! sensor stops answering.
//!
//! - **Can fly** ([`Readiness::can_fly`]): both BMI088 parts and the BMP388
//!   answered with their chip ids and configured, the estimator is aligned,
//!   the battery is above [`Config::battery_floor_v`].
//! - **Tumbled**: the body's z axis more than [`Config::tilt_limit_deg`]
//!   (60°) from vertical for [`Config::tilt_time_us`] (1 s), or more than
//!   [`Config::upside_down_deg`] (≈ 101.5°, the official firmware's
//!   acc z < −0.2 g) for [`Config::upside_down_time_us`] (0.1 s): motors
//!   off, latched until disarmed.
//! - **Sensor lost**: no good IMU sample for [`Config::imu_timeout_us`]
//!   (10 ms: ten missed samples at 1 kHz) while armed → failsafe descent;
//!   on the ground it only refuses to arm. Every missed or bad sample is
//!   counted by kind.

use crate::SensorError;

/// The supervisor's limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Config {
    /// Lowest battery voltage to arm at, V (1S LiPo; the Crazyflie warns at 3.2 V).
    pub battery_floor_v: f32,
    /// Tilt beyond which the tumble clock runs, degrees.
    pub tilt_limit_deg: f32,
    /// Time beyond the tilt limit that is a tumble, µs.
    pub tilt_time_us: u64,
    /// Tilt taken as upside down, degrees.
    pub upside_down_deg: f32,
    /// Time upside down that is a tumble, µs.
    pub upside_down_time_us: u64,
    /// Longest gap between good IMU samples while flying, µs.
    pub imu_timeout_us: u64,
}

impl Config {
    /// The values stated in the module's documentation.
    pub const DEFAULT: Config = Config {
        battery_floor_v: 3.2,
        tilt_limit_deg: 60.0,
        tilt_time_us: 1_000_000,
        upside_down_deg: 101.5,
        upside_down_time_us: 100_000,
        imu_timeout_us: 10_000,
    };
}

/// Why the vehicle may not arm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum CannotFly {
    /// A sensor did not start (the driver's error names it and why).
    Sensor(SensorError),
    /// The estimator has not aligned yet.
    NotAligned,
    /// The battery is below the floor (its voltage, V).
    BatteryLow(f32),
    /// The supervisor latched a fault (tumble, lost sensor) that a disarm clears.
    Latched(Fault),
}

impl core::fmt::Display for CannotFly {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CannotFly::Sensor(e) => write!(f, "cannot fly: {e}"),
            CannotFly::NotAligned => write!(f, "cannot fly: estimator not aligned (keep the vehicle still)"),
            CannotFly::BatteryLow(v) => write!(f, "cannot fly: battery {v:.2} V below the floor"),
            CannotFly::Latched(x) => write!(f, "cannot fly: {x} (disarm to clear)"),
        }
    }
}

/// What is known at arming time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Readiness {
    /// The BMI088's start-up result.
    pub imu: Result<(), SensorError>,
    /// The BMP388's start-up result.
    pub baro: Result<(), SensorError>,
    /// The estimator is aligned.
    pub aligned: bool,
    /// Battery voltage, V.
    pub battery_v: f32,
}

impl Readiness {
    /// The first check that fails, or `Ok`.
    pub fn can_fly(&self, cfg: &Config) -> Result<(), CannotFly> {
        self.imu.map_err(CannotFly::Sensor)?;
        self.baro.map_err(CannotFly::Sensor)?;
        if !self.aligned {
            return Err(CannotFly::NotAligned);
        }
        if self.battery_v.is_nan() || self.battery_v < cfg.battery_floor_v {
            return Err(CannotFly::BatteryLow(self.battery_v));
        }
        Ok(())
    }
}

/// A latched fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Tilted beyond the limits for too long (or the attitude is not finite).
    Tumbled,
    /// The IMU went silent on the ground.
    ImuLost,
}

impl core::fmt::Display for Fault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Fault::Tumbled => write!(f, "tumbled"),
            Fault::ImuLost => write!(f, "IMU lost"),
        }
    }
}

/// What the motors should do now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// Disarmed: motors off.
    Idle,
    /// Fly the controller's output.
    Fly,
    /// Level and descend (the IMU is silent; the estimator predicts).
    FailsafeDescent,
    /// Motors off now (a tumble).
    MotorsOff,
}

/// Counts of every bad or missing sample, by kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// IMU samples that were bus errors.
    pub imu_bus: u32,
    /// IMU samples refused as frozen or implausible.
    pub imu_bad: u32,
    /// Times the IMU went silent past the timeout.
    pub imu_timeouts: u32,
    /// Tumbles.
    pub tumbles: u32,
}

/// The supervisor's state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Supervisor {
    cfg: Config,
    armed: bool,
    latched: Option<Fault>,
    failsafe: bool,
    last_good_imu_us: u64,
    tilted_since_us: Option<u64>,
    counters: Counters,
}

impl Supervisor {
    /// Disarmed, nothing latched, the IMU "last seen" at `now_us`.
    pub fn new(cfg: Config, now_us: u64) -> Self {
        Self {
            cfg,
            armed: false,
            latched: None,
            failsafe: false,
            last_good_imu_us: now_us,
            tilted_since_us: None,
            counters: Counters::default(),
        }
    }

    /// Arms if every check passes (and nothing is latched).
    pub fn arm(&mut self, r: &Readiness) -> Result<(), CannotFly> {
        if let Some(f) = self.latched {
            return Err(CannotFly::Latched(f));
        }
        r.can_fly(&self.cfg)?;
        self.armed = true;
        Ok(())
    }

    /// Disarms and clears a latched fault.
    pub fn disarm(&mut self) {
        self.armed = false;
        self.latched = None;
        self.failsafe = false;
        self.tilted_since_us = None;
    }

    /// Armed now.
    pub fn armed(&self) -> bool {
        self.armed
    }

    /// The latched fault, if any.
    pub fn latched(&self) -> Option<Fault> {
        self.latched
    }

    /// The counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// An IMU read's outcome at `now_us`.
    pub fn imu_result<T>(&mut self, now_us: u64, r: &Result<T, SensorError>) {
        match r {
            Ok(_) => self.last_good_imu_us = now_us,
            Err(SensorError::Bus { .. } | SensorError::Timeout { .. }) => {
                self.counters.imu_bus = self.counters.imu_bus.saturating_add(1)
            }
            Err(_) => self.counters.imu_bad = self.counters.imu_bad.saturating_add(1),
        }
    }

    /// One supervisor step at `now_us` with the estimated attitude's
    /// `cos_tilt` (the body z axis against vertical: R₃₃ of body→NED).
    pub fn step(&mut self, now_us: u64, cos_tilt: f32) -> Command {
        let silent = now_us.saturating_sub(self.last_good_imu_us) > self.cfg.imu_timeout_us;
        if silent && !self.failsafe && self.armed {
            self.counters.imu_timeouts = self.counters.imu_timeouts.saturating_add(1);
            self.failsafe = true;
        }
        if !silent {
            self.failsafe = false;
        }
        if self.armed && self.tumbled(now_us, cos_tilt) {
            self.counters.tumbles = self.counters.tumbles.saturating_add(1);
            self.latched = Some(Fault::Tumbled);
            self.armed = false;
        }
        if !self.armed {
            if silent && self.latched.is_none() {
                self.latched = Some(Fault::ImuLost);
            }
            return match self.latched {
                Some(Fault::Tumbled) => Command::MotorsOff,
                _ => Command::Idle,
            };
        }
        if self.failsafe {
            Command::FailsafeDescent
        } else {
            Command::Fly
        }
    }

    fn tumbled(&mut self, now_us: u64, cos_tilt: f32) -> bool {
        if !cos_tilt.is_finite() {
            return true;
        }
        let cos_deg = |d: f32| libm::cosf(d.to_radians());
        if cos_tilt >= cos_deg(self.cfg.tilt_limit_deg) {
            self.tilted_since_us = None;
            return false;
        }
        let since = *self.tilted_since_us.get_or_insert(now_us);
        let held = now_us.saturating_sub(since);
        held > self.cfg.tilt_time_us
            || (cos_tilt < cos_deg(self.cfg.upside_down_deg) && held > self.cfg.upside_down_time_us)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::ErrorKind;

    fn ready() -> Readiness {
        Readiness {
            imu: Ok(()),
            baro: Ok(()),
            aligned: true,
            battery_v: 3.9,
        }
    }

    #[test]
    fn each_can_fly_check_refuses_by_name() {
        let c = Config::DEFAULT;
        assert_eq!(ready().can_fly(&c), Ok(()));
        let id = SensorError::ChipId {
            device: "BMP388",
            expected: 0x50,
            found: 0x60,
        };
        let r = Readiness {
            baro: Err(id),
            ..ready()
        };
        assert_eq!(
            r.can_fly(&c).unwrap_err().to_string(),
            "cannot fly: BMP388: chip id 0x60, expected 0x50"
        );
        assert_eq!(
            Readiness {
                aligned: false,
                ..ready()
            }
            .can_fly(&c),
            Err(CannotFly::NotAligned)
        );
        let low = Readiness {
            battery_v: 3.1,
            ..ready()
        }
        .can_fly(&c)
        .unwrap_err();
        assert_eq!(low.to_string(), "cannot fly: battery 3.10 V below the floor");
        assert!(Readiness {
            battery_v: f32::NAN,
            ..ready()
        }
        .can_fly(&c)
        .is_err());
    }

    #[test]
    fn tilt_beyond_60_degrees_for_a_second_or_upside_down_for_a_tenth_stops_the_motors() {
        let cos = |deg: f32| deg.to_radians().cos();
        let mut s = Supervisor::new(Config::DEFAULT, 0);
        s.arm(&ready()).unwrap();
        let mut t = 0u64;
        let mut fly = |s: &mut Supervisor, deg: f32, for_us: u64| {
            let mut last = Command::Idle;
            let end = t + for_us;
            while t < end {
                s.imu_result::<()>(t, &Ok(()));
                last = s.step(t, cos(deg));
                t += 1000;
            }
            last
        };
        // 55° for 5 s (a hard manoeuvre): flying. 65° for 0.9 s: still flying.
        assert_eq!(fly(&mut s, 55.0, 5_000_000), Command::Fly);
        assert_eq!(fly(&mut s, 65.0, 900_000), Command::Fly);
        assert_eq!(fly(&mut s, 10.0, 1000), Command::Fly);
        // 65° for 1.1 s: motors off, latched; arming is refused until a disarm.
        assert_eq!(fly(&mut s, 65.0, 1_100_000), Command::MotorsOff);
        assert_eq!(s.arm(&ready()), Err(CannotFly::Latched(Fault::Tumbled)));
        assert_eq!(fly(&mut s, 0.0, 1000), Command::MotorsOff);
        s.disarm();
        s.arm(&ready()).unwrap();
        // Upside down (170°): 90 ms flying, 110 ms off.
        assert_eq!(fly(&mut s, 170.0, 90_000), Command::Fly);
        assert_eq!(fly(&mut s, 170.0, 20_000), Command::MotorsOff);
        assert_eq!(s.counters().tumbles, 2);
        // A NaN attitude is a tumble at once.
        s.disarm();
        s.arm(&ready()).unwrap();
        assert_eq!(fly(&mut s, f32::NAN, 1000), Command::MotorsOff);
    }

    /// The supervisor takes its IMU results from an [`crate::ImuSource`]:
    /// here the BMI088 driver on a mock bus whose accelerometer stops
    /// answering mid-flight.
    #[test]
    fn a_bmi088_that_stops_answering_puts_the_flight_into_failsafe() {
        use crate::{bmi088::Bmi088, ImuSource};
        use embedded_hal::i2c::NoAcknowledgeSource;
        use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};
        let good = |k: u8| {
            vec![
                T::write_read(0x69, vec![0x02], vec![k, 0, 0, 0, 0, 0]),
                T::write_read(0x18, vec![0x12], vec![0, 0, 0, 0, 0x55, 0x05]),
            ]
        };
        let nack = vec![
            T::write_read(0x69, vec![0x02], vec![0; 6]),
            T::write_read(0x18, vec![0x12], vec![0; 6])
                .with_error(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)),
        ];
        let mut t = Vec::new();
        for k in 0..5 {
            t.extend(good(k));
        }
        for _ in 0..12 {
            t.extend(nack.clone());
        }
        let mut i2c = Mock::new(&t);
        let mut imu = Bmi088::new(i2c.clone());
        let mut s = Supervisor::new(Config::DEFAULT, 0);
        s.arm(&ready()).unwrap();
        let mut commands = Vec::new();
        for k in 0..17u64 {
            let now = k * 1000;
            let r = imu.sample();
            s.imu_result(now, &r);
            commands.push(s.step(now, 1.0));
        }
        // Five good samples, then silence: flying until 10 ms after the last
        // good one (4 ms), failsafe from 15 ms on.
        assert!(commands[..15].iter().all(|c| *c == Command::Fly), "{commands:?}");
        assert_eq!(&commands[15..], &[Command::FailsafeDescent; 2]);
        assert_eq!((s.counters().imu_bus, s.counters().imu_timeouts), (12, 1));
        i2c.done();
    }

    #[test]
    fn a_silent_imu_in_flight_is_a_counted_failsafe_descent_and_recovers() {
        let mut s = Supervisor::new(Config::DEFAULT, 0);
        s.arm(&ready()).unwrap();
        let bus = Err::<(), _>(SensorError::Bus {
            device: "BMI088 gyroscope",
            kind: ErrorKind::Bus,
        });
        let frozen = Err::<(), _>(SensorError::Frozen {
            device: "BMI088",
            repeats: 10,
        });
        s.imu_result::<()>(0, &Ok(()));
        // 10 ms of errors: still flying (the limit is "more than 10 ms").
        for t in (1000..=10_000).step_by(1000) {
            s.imu_result(t, if t % 2000 == 0 { &bus } else { &frozen });
            assert_eq!(s.step(t, 1.0), Command::Fly, "{t}");
        }
        s.imu_result(11_000, &bus);
        assert_eq!(s.step(11_000, 1.0), Command::FailsafeDescent);
        assert_eq!(s.step(50_000, 1.0), Command::FailsafeDescent);
        let c = s.counters();
        assert_eq!((c.imu_bus, c.imu_bad, c.imu_timeouts), (6, 5, 1));
        // Samples again: back to flying; the timeout was counted once.
        s.imu_result::<()>(51_000, &Ok(()));
        assert_eq!(s.step(51_000, 1.0), Command::Fly);
        assert_eq!(s.counters().imu_timeouts, 1);
        // On the ground a silent IMU latches and refuses arming.
        s.disarm();
        assert_eq!(s.step(200_000, 1.0), Command::Idle);
        assert_eq!(s.arm(&ready()), Err(CannotFly::Latched(Fault::ImuLost)));
    }
}
