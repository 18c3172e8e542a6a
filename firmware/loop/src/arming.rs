//! One arming state and one arming check for every protocol (CRTP's
//! supervisor port and platform commands, MAVLink's
//! `MAV_CMD_COMPONENT_ARM_DISARM`): [`Arming`] holds whether the motors may
//! run and the supervisor's latches (locked, tumbled); [`Arming::arm`]
//! checks what must hold first, in one order, and refuses with a typed
//! [`ArmRefusal`] whose `Display` is what a ground station or cflib's
//! console shows after "arming refused: ".
//!
//! A protocol passes what its vehicle monitors ([`ArmingState`]); what it
//! does not monitor is `None` (PX4's HIL gives no battery reading). Only
//! the Crazyflie's supervisor locks ([`Arming::lock`], its emergency stop)
//! or latches a tumble ([`Arming::tumble`]); PX4's lockdown disarms.

use crate::nav::NavMode;

/// What the arming check looks at besides the latches [`Arming`] holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArmingState {
    /// A sensor the board monitors that stopped answering: its part and
    /// what went wrong (`None`: every monitored sensor answers).
    pub sensor_down: Option<(&'static str, &'static str)>,
    /// The battery, V: `None`, not monitored; `Some(None)`, no reading yet.
    pub battery_v: Option<Option<f32>>,
    /// Arming is refused below this battery voltage, V.
    pub battery_floor_v: f32,
    /// The navigator's mode (a navigating one without an estimate counts as
    /// its failsafe).
    pub nav: NavMode,
    /// The vehicle is started: its controller designed, its mixer set.
    pub started: bool,
}

/// Why arming is refused.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ArmRefusal {
    /// A monitored sensor stopped answering.
    SensorDown {
        /// The part ("BMI088 gyroscope").
        device: &'static str,
        /// What went wrong ("wrong chip id").
        why: &'static str,
    },
    /// The battery is monitored and has not been read yet.
    NoBatteryReading,
    /// The battery, V, is below the floor, V.
    BatteryLow {
        /// The reading, V.
        v: f32,
        /// The floor, V.
        floor_v: f32,
    },
    /// Locked by the supervisor: restart.
    Locked,
    /// Tumbled: recover first.
    Tumbled,
    /// The estimator is aligning.
    Aligning,
    /// The estimator is in its failsafe.
    EstimatorFailsafe,
    /// The vehicle is not started (no controller designed yet).
    NotStarted,
    /// The controller could not be designed afresh for the flight.
    DesignFailed,
}

impl core::fmt::Display for ArmRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ArmRefusal::SensorDown { device, why } => write!(f, "{device}: {why}"),
            ArmRefusal::NoBatteryReading => f.write_str("no battery reading yet"),
            ArmRefusal::BatteryLow { v, floor_v } => {
                write!(f, "battery {} V below {} V", Centi(*v), Centi(*floor_v))
            }
            ArmRefusal::Locked => f.write_str("locked: restart"),
            ArmRefusal::Tumbled => f.write_str("tumbled: recover"),
            ArmRefusal::Aligning => f.write_str("estimator aligning"),
            ArmRefusal::EstimatorFailsafe => f.write_str("estimator failsafe"),
            ArmRefusal::NotStarted => f.write_str("not started"),
            ArmRefusal::DesignFailed => f.write_str("controller design failed"),
        }
    }
}

/// A value with two decimals, as `{:.2}` writes it, without core's float
/// formatting: the refusal is reachable from every image's arming path, and
/// that machinery is ≈ 20 KiB of flash on the M4 (`firmware-mavlink` has
/// no other use for it).
struct Centi(f32);

impl core::fmt::Display for Centi {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let v = self.0;
        if v.is_nan() {
            return f.write_str("NaN");
        }
        if v.is_infinite() {
            return f.write_str(if v > 0.0 { "inf" } else { "-inf" });
        }
        if v.abs() >= 1e7 {
            // Past what an i32 of hundredths holds: no voltage, said so.
            return f.write_str(if v > 0.0 { ">1e7" } else { "<-1e7" });
        }
        let c = libm::roundf(v * 100.0) as i32;
        let sign = if c < 0 { "-" } else { "" };
        let c = c.unsigned_abs();
        write!(f, "{sign}{}.{:02}", c / 100, c % 100)
    }
}

/// Whether the motors may run, and the supervisor's latches: a lock (the
/// emergency stop; only a restart clears it) and a tumble (until a
/// recovery). Disarmed and clear at start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Arming {
    armed: bool,
    locked: bool,
    tumbled: bool,
}

impl Arming {
    /// Disarmed, neither locked nor tumbled.
    pub const fn new() -> Self {
        Self {
            armed: false,
            locked: false,
            tumbled: false,
        }
    }

    /// Armed: the motors may run.
    pub fn armed(&self) -> bool {
        self.armed
    }

    /// Locked by an emergency stop, until a restart.
    pub fn locked(&self) -> bool {
        self.locked
    }

    /// A tumble was seen, until a recovery.
    pub fn tumbled(&self) -> bool {
        self.tumbled
    }

    /// Arms if the check passes on `s` and this state's latches (the
    /// first of a sensor down, the battery, the lock, the tumble, the
    /// estimator and the start refuses) and then `prepare`, the vehicle's last step
    /// before its motors may run (a controller designed afresh), succeeds:
    /// `Some` of what `prepare` gave; armed already: `None`, nothing run.
    pub fn arm<T>(
        &mut self,
        s: &ArmingState,
        prepare: impl FnOnce() -> Result<T, ArmRefusal>,
    ) -> Result<Option<T>, ArmRefusal> {
        if self.armed {
            return Ok(None);
        }
        self.may_arm(s)?;
        let prepared = prepare()?;
        self.armed = true;
        Ok(Some(prepared))
    }

    /// The check [`Arming::arm`] runs, on `s` and this state's latches,
    /// without arming: whether it would pass, or its refusal.
    pub fn may_arm(&self, s: &ArmingState) -> Result<(), ArmRefusal> {
        // The first that refuses: a sensor, the battery, the lock, the
        // tumble, the estimator, the start.
        if let Some((device, why)) = s.sensor_down {
            return Err(ArmRefusal::SensorDown { device, why });
        }
        match s.battery_v {
            Some(None) => return Err(ArmRefusal::NoBatteryReading),
            // A NaN reading refuses too.
            Some(Some(v)) if v.is_nan() || v < s.battery_floor_v => {
                return Err(ArmRefusal::BatteryLow {
                    v,
                    floor_v: s.battery_floor_v,
                })
            }
            _ => {}
        }
        if self.locked {
            return Err(ArmRefusal::Locked);
        }
        if self.tumbled {
            return Err(ArmRefusal::Tumbled);
        }
        match s.nav {
            NavMode::Aligning => Err(ArmRefusal::Aligning),
            NavMode::Failsafe => Err(ArmRefusal::EstimatorFailsafe),
            NavMode::Navigating if !s.started => Err(ArmRefusal::NotStarted),
            NavMode::Navigating => Ok(()),
        }
    }

    /// Disarmed (the latches kept).
    pub fn disarm(&mut self) {
        self.armed = false;
    }

    /// The emergency stop: disarmed and locked until a restart.
    pub fn lock(&mut self) {
        self.armed = false;
        self.locked = true;
    }

    /// A tumble seen: arming is refused until [`Arming::recover`]. The
    /// arming itself is the vehicle's to end (the Crazyflie's supervisor
    /// stops the motors and stays armed).
    pub fn tumble(&mut self) {
        self.tumbled = true;
    }

    /// Clears a tumble, unless locked or `flying`; whether it did.
    pub fn recover(&mut self, flying: bool) -> bool {
        if self.locked || flying {
            return false;
        }
        self.tumbled = false;
        true
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A state every check passes: sensors up, a full battery, the
    /// estimator navigating, started.
    pub(crate) fn ready() -> ArmingState {
        ArmingState {
            sensor_down: None,
            battery_v: Some(Some(4.0)),
            battery_floor_v: 3.2,
            nav: NavMode::Navigating,
            started: true,
        }
    }

    /// A disarmed state with the latches given.
    fn latched(locked: bool, tumbled: bool) -> Arming {
        let mut a = Arming::new();
        if locked {
            a.lock();
        }
        if tumbled {
            a.tumble();
        }
        a
    }

    /// Arms `a` on `s` with nothing to prepare.
    fn arm(mut a: Arming, s: &ArmingState) -> Result<(), ArmRefusal> {
        let r = a.arm(s, || Ok(())).map(|_| ());
        assert_eq!(a.armed(), r.is_ok());
        r
    }

    /// Each condition refuses on its own, by name, and the first in the
    /// check's order wins when several hold; what is not monitored does
    /// not refuse.
    #[test]
    fn each_condition_refuses_by_name_in_order() {
        let clear = Arming::new();
        assert_eq!(arm(clear, &ready()), Ok(()));
        let unmonitored = ArmingState {
            battery_v: None,
            ..ready()
        };
        assert_eq!(arm(clear, &unmonitored), Ok(()));
        let cases: [(ArmingState, Arming, ArmRefusal, &str); 9] = [
            (
                ArmingState {
                    sensor_down: Some(("BMI088 gyroscope", "wrong chip id")),
                    ..ready()
                },
                clear,
                ArmRefusal::SensorDown {
                    device: "BMI088 gyroscope",
                    why: "wrong chip id",
                },
                "BMI088 gyroscope: wrong chip id",
            ),
            (
                ArmingState {
                    battery_v: Some(None),
                    ..ready()
                },
                clear,
                ArmRefusal::NoBatteryReading,
                "no battery reading yet",
            ),
            (
                ArmingState {
                    battery_v: Some(Some(3.1)),
                    ..ready()
                },
                clear,
                ArmRefusal::BatteryLow { v: 3.1, floor_v: 3.2 },
                "battery 3.10 V below 3.20 V",
            ),
            (ready(), latched(true, false), ArmRefusal::Locked, "locked: restart"),
            (ready(), latched(false, true), ArmRefusal::Tumbled, "tumbled: recover"),
            (
                ArmingState {
                    nav: NavMode::Aligning,
                    ..ready()
                },
                clear,
                ArmRefusal::Aligning,
                "estimator aligning",
            ),
            (
                ArmingState {
                    nav: NavMode::Failsafe,
                    ..ready()
                },
                clear,
                ArmRefusal::EstimatorFailsafe,
                "estimator failsafe",
            ),
            (
                ArmingState {
                    started: false,
                    ..ready()
                },
                clear,
                ArmRefusal::NotStarted,
                "not started",
            ),
            (
                ArmingState {
                    battery_v: Some(Some(f32::NAN)),
                    ..ready()
                },
                clear,
                ArmRefusal::BatteryLow {
                    v: f32::NAN,
                    floor_v: 3.2,
                },
                "battery NaN V below 3.20 V",
            ),
        ];
        for (state, latches, want, text) in cases {
            let got = arm(latches, &state).unwrap_err();
            assert_eq!(format!("{got}"), text);
            if !matches!(want, ArmRefusal::BatteryLow { .. }) {
                assert_eq!(got, want);
            }
        }
        // The first in order wins: a dead sensor before a low battery
        // before the latches before the estimator.
        let all = ArmingState {
            sensor_down: Some(("BMP388", "no answer")),
            battery_v: Some(Some(3.0)),
            nav: NavMode::Aligning,
            started: false,
            ..ready()
        };
        let both = latched(true, true);
        assert!(matches!(arm(both, &all), Err(ArmRefusal::SensorDown { .. })));
        let no_sensor = ArmingState {
            sensor_down: None,
            ..all
        };
        assert!(matches!(arm(both, &no_sensor), Err(ArmRefusal::BatteryLow { .. })));
        let charged = ArmingState {
            battery_v: None,
            ..no_sensor
        };
        assert_eq!(arm(both, &charged), Err(ArmRefusal::Locked));
        assert_eq!(arm(latched(false, true), &charged), Err(ArmRefusal::Tumbled));
    }

    /// The preparation runs after the check and only then: its refusal
    /// leaves the vehicle disarmed; armed already, nothing runs again.
    #[test]
    fn prepare_runs_once_after_the_check() {
        let mut a = Arming::new();
        let mut ran = 0;
        let aligning = ArmingState {
            nav: NavMode::Aligning,
            ..ready()
        };
        let refused = a.arm(&aligning, || {
            ran += 1;
            Ok(())
        });
        assert_eq!(refused, Err(ArmRefusal::Aligning));
        assert_eq!(
            a.arm(&ready(), || Err::<(), _>(ArmRefusal::DesignFailed)),
            Err(ArmRefusal::DesignFailed)
        );
        assert!(!a.armed() && ran == 0);
        for want in [Some(1), None] {
            let got = a.arm(&ready(), || {
                ran += 1;
                Ok(ran)
            });
            assert_eq!(got, Ok(want));
        }
        assert!(a.armed() && ran == 1);
    }

    /// The emergency stop disarms and holds until a restart; a tumble
    /// holds until a recovery, which a lock or a flight refuses.
    #[test]
    fn latches_hold_until_cleared() {
        let mut a = Arming::new();
        assert_eq!(a.may_arm(&ready()), Ok(()));
        assert!(!a.armed(), "asking does not arm");
        a.arm(&ready(), || Ok(())).unwrap();
        a.tumble();
        assert_eq!(a.may_arm(&ready()), Err(ArmRefusal::Tumbled));
        assert!(a.armed() && a.tumbled(), "a tumble does not disarm by itself");
        assert!(!a.recover(true), "not while flying");
        assert!(a.recover(false) && !a.tumbled());
        a.lock();
        assert!(!a.armed() && a.locked());
        a.tumble();
        assert!(!a.recover(false) && a.tumbled(), "locked: no recovery");
        a.disarm();
        assert_eq!(a.arm(&ready(), || Ok(())), Err(ArmRefusal::Locked));
        assert!(!a.armed());
        assert!(
            Arming::new().arm(&ready(), || Ok(())).is_ok(),
            "a restart clears the lock"
        );
    }

    /// The voltages are written as `{:.2}` writes them.
    #[test]
    fn volts_have_two_decimals_as_core_writes_them() {
        for v in [0.0f32, 3.1, 3.2, 3.999, 4.2, 12.6, 0.004, -1.25, 0.5, 100.0] {
            assert_eq!(format!("{}", Centi(v)), format!("{v:.2}"), "{v}");
        }
        assert_eq!(format!("{}", Centi(f32::NAN)), "NaN");
        assert_eq!(format!("{}", Centi(f32::INFINITY)), "inf");
    }
}
