//! One arming check for every protocol (CRTP's supervisor port and
//! platform commands, MAVLink's `MAV_CMD_COMPONENT_ARM_DISARM`): what must
//! hold before the motors may run, checked in one order, and a typed
//! refusal ([`ArmRefusal`]) whose `Display` is what a ground station or
//! cflib's console shows after "arming refused: ".
//!
//! A protocol passes what its vehicle monitors; what it does not monitor
//! is `None` or `false` (PX4's HIL gives no battery reading, and only the
//! Crazyflie's supervisor locks or sees a tumble).

use crate::nav::NavMode;

/// What the arming check looks at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArmingState {
    /// A sensor the board monitors that stopped answering: its part and
    /// what went wrong (`None`: every monitored sensor answers).
    pub sensor_down: Option<(&'static str, &'static str)>,
    /// The battery, V: `None`, not monitored; `Some(None)`, no reading yet.
    pub battery_v: Option<Option<f32>>,
    /// Arming is refused below this battery voltage, V.
    pub battery_floor_v: f32,
    /// The supervisor locked the vehicle (until a restart).
    pub locked: bool,
    /// The supervisor saw a tumble (until a recovery).
    pub tumbled: bool,
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

/// The arming check: the first of the sensors, the battery, the
/// supervisor's lock and tumble, the estimator and the start that refuses.
pub fn check(s: &ArmingState) -> Result<(), ArmRefusal> {
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
    if s.locked {
        return Err(ArmRefusal::Locked);
    }
    if s.tumbled {
        return Err(ArmRefusal::Tumbled);
    }
    match s.nav {
        NavMode::Aligning => Err(ArmRefusal::Aligning),
        NavMode::Failsafe => Err(ArmRefusal::EstimatorFailsafe),
        NavMode::Navigating if !s.started => Err(ArmRefusal::NotStarted),
        NavMode::Navigating => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ready() -> ArmingState {
        ArmingState {
            sensor_down: None,
            battery_v: Some(Some(4.0)),
            battery_floor_v: 3.2,
            locked: false,
            tumbled: false,
            nav: NavMode::Navigating,
            started: true,
        }
    }

    /// Each condition refuses on its own, by name, and the first in the
    /// check's order wins when several hold; what is not monitored does
    /// not refuse.
    #[test]
    fn each_condition_refuses_by_name_in_order() {
        assert_eq!(check(&ready()), Ok(()));
        let unmonitored = ArmingState {
            battery_v: None,
            ..ready()
        };
        assert_eq!(check(&unmonitored), Ok(()));
        let cases: [(ArmingState, ArmRefusal, &str); 9] = [
            (
                ArmingState {
                    sensor_down: Some(("BMI088 gyroscope", "wrong chip id")),
                    ..ready()
                },
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
                ArmRefusal::NoBatteryReading,
                "no battery reading yet",
            ),
            (
                ArmingState {
                    battery_v: Some(Some(3.1)),
                    ..ready()
                },
                ArmRefusal::BatteryLow { v: 3.1, floor_v: 3.2 },
                "battery 3.10 V below 3.20 V",
            ),
            (
                ArmingState {
                    locked: true,
                    ..ready()
                },
                ArmRefusal::Locked,
                "locked: restart",
            ),
            (
                ArmingState {
                    tumbled: true,
                    ..ready()
                },
                ArmRefusal::Tumbled,
                "tumbled: recover",
            ),
            (
                ArmingState {
                    nav: NavMode::Aligning,
                    ..ready()
                },
                ArmRefusal::Aligning,
                "estimator aligning",
            ),
            (
                ArmingState {
                    nav: NavMode::Failsafe,
                    ..ready()
                },
                ArmRefusal::EstimatorFailsafe,
                "estimator failsafe",
            ),
            (
                ArmingState {
                    started: false,
                    ..ready()
                },
                ArmRefusal::NotStarted,
                "not started",
            ),
            (
                ArmingState {
                    battery_v: Some(Some(f32::NAN)),
                    ..ready()
                },
                ArmRefusal::BatteryLow {
                    v: f32::NAN,
                    floor_v: 3.2,
                },
                "battery NaN V below 3.20 V",
            ),
        ];
        for (state, want, text) in cases {
            let got = check(&state).unwrap_err();
            assert_eq!(format!("{got}"), text);
            if !matches!(want, ArmRefusal::BatteryLow { .. }) {
                assert_eq!(got, want);
            }
        }
        // The first in order wins: a dead sensor before a low battery
        // before the estimator.
        let all = ArmingState {
            sensor_down: Some(("BMP388", "no answer")),
            battery_v: Some(Some(3.0)),
            locked: true,
            tumbled: true,
            nav: NavMode::Aligning,
            started: false,
            ..ready()
        };
        assert!(matches!(check(&all), Err(ArmRefusal::SensorDown { .. })));
        let no_sensor = ArmingState {
            sensor_down: None,
            ..all
        };
        assert!(matches!(check(&no_sensor), Err(ArmRefusal::BatteryLow { .. })));
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
