//! The board's part of the supervisor. The vehicle's own
//! (`fc_crtp::vehicle::CrtpShared` with `fc_loop::supervisor`) decides:
//! arming (estimator aligned, battery above 3.2 V, not tumbled or locked,
//! the board's sensors up), tumble (beyond 60°: motors off), every IMU
//! sample (a bad or missing one replaced by the last good one for 10 ms,
//! then a failsafe descent). The board tells it two things:
//!
//! - **whether its sensors started** ([`sensors_up`]): both BMI088 parts
//!   and the BMP388 answered with their chip ids and took their
//!   configuration. Arming is refused while one did not, naming it
//!   ([`down`]: the part and a short reason; the driver's full
//!   [`SensorError`] goes to the image's log);
//! - **each sample or its absence**: an [`crate::ImuSource`]'s error is a
//!   missing sample (`None` to `CrtpShared::imu_begin`), counted there.
//!
//! A data-ready line that stops altogether runs no step at all; the IWDG,
//! fed only while the IMU task steps (`fc_stm32f405::watchdog`), then resets the
//! chip and the motors stop.

use crate::SensorError;
use fc_loop::supervisor::SensorDown;

/// `e` as the vehicle's arming refusal names it: the part and what went
/// wrong, in a few words.
pub fn down(e: &SensorError) -> SensorDown {
    let why = match e {
        SensorError::Bus { .. } => "no answer on I2C",
        SensorError::ChipId { .. } => "wrong chip id",
        SensorError::Config { .. } => "configuration did not read back",
        SensorError::DeviceError { .. } => "reports an error",
        SensorError::Frozen { .. } => "frozen",
        SensorError::Implausible { .. } => "implausible reading",
        SensorError::Timeout { .. } => "not ready in time",
    };
    SensorDown {
        device: e.device(),
        why,
    }
}

/// The start-up results of the IMU and the barometer as the vehicle takes
/// them (`CrtpShared::set_sensors`): the first that failed, or `Ok`.
pub fn sensors_up(imu: Result<(), SensorError>, baro: Result<(), SensorError>) -> Result<(), SensorDown> {
    imu.and(baro).map_err(|e| down(&e))
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::ErrorKind;
    use fc_loop::supervisor::{ImuGuard, ImuOutcome, IMU_TIMEOUT_US};

    #[test]
    fn a_sensor_that_did_not_start_is_named_with_what_went_wrong() {
        let id = SensorError::ChipId {
            device: "BMP388",
            expected: 0x50,
            found: 0x60,
        };
        assert_eq!(sensors_up(Ok(()), Ok(())), Ok(()));
        assert_eq!(
            sensors_up(Ok(()), Err(id)).unwrap_err().to_string(),
            "BMP388: wrong chip id"
        );
        let bus = SensorError::Bus {
            device: "BMI088 gyroscope",
            kind: ErrorKind::Bus,
        };
        // The IMU first.
        assert_eq!(
            sensors_up(Err(bus), Err(id)).unwrap_err().to_string(),
            "BMI088 gyroscope: no answer on I2C"
        );
    }

    /// The vehicle's guard takes the BMI088 driver's samples (an
    /// [`crate::ImuSource`], on a mock bus whose accelerometer stops
    /// answering mid-flight): each failed read is a missing sample, the
    /// last good one flown, until 10 ms after it.
    #[test]
    fn a_bmi088_that_stops_answering_is_held_for_10_ms_then_silent() {
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
        let mut guard = ImuGuard::new();
        let mut silent = Vec::new();
        let mut last_good = None;
        for k in 0..17u64 {
            let now = k * 1000;
            let s = imu.sample().ok().map(|s| fc_core::estimate::ImuSample {
                gyro_frd_radps: s.gyro_frd_radps.into(),
                accel_frd_mps2: s.accel_frd_mps2.into(),
            });
            let (flown, outcome) = guard.take(now, s.as_ref());
            if outcome == ImuOutcome::Good {
                last_good = flown;
            } else {
                assert_eq!(flown, last_good, "the last good sample is flown");
            }
            silent.push(guard.silent());
        }
        // Five good samples (0–4 ms), then NACKs: silent from more than
        // 10 ms after the last good one, i.e. from 15 ms.
        let first = (IMU_TIMEOUT_US / 1000 + 5) as usize;
        assert!(silent[..first].iter().all(|s| !s), "{silent:?}");
        assert!(silent[first..].iter().all(|s| *s), "{silent:?}");
        let c = guard.counters();
        assert_eq!((c.missing, c.held, c.timeouts), (12, 12, 1));
        i2c.done();
    }
}
