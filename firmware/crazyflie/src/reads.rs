//! What the sensor bus (I2C3) reads and when, on its interrupts: every
//! gyroscope data-ready (1 kHz) starts an IMU sample
//! ([`bmi088::SampleReader`]: the gyroscope's six bytes, then the
//! accelerometer's); every [`BARO_EVERY`]th sample, once it is read, the
//! barometer's six bytes follow ([`bmp388::SampleReader`], 50 Hz, the
//! part's output rate). One transfer is on the bus at a time, the IMU's
//! first: the IMU sample is handed on the moment it is read, and the
//! barometer's read is what waits.
//!
//! The bound is the IMU's period: whatever is still on the bus at the next
//! data-ready is abandoned and reported (an IMU sample as missing, a
//! barometer reading as timed out). At 400 kHz the IMU's two bursts take
//! about 0.45 ms and the barometer's about 0.23 ms (9 bytes of 9 clocks
//! each per burst, with the repeated START), so all three fit in 1 ms.

use crate::bmi088::{self, ImuSample};
use crate::bmp388::{self, BaroSample, Calibration};
use crate::i2c::Regs;
use crate::SensorError;

/// The barometer is read after every this many IMU samples (1 kHz / 20 =
/// 50 Hz, the BMP388's output rate as configured).
pub const BARO_EVERY: u32 = 20;

/// What an interrupt finished: an IMU sample (or why there is none), a
/// barometer reading (or why there is none), or nothing yet.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Finished {
    /// The IMU sample read, or why it is missing.
    pub imu: Option<Result<ImuSample, SensorError>>,
    /// The barometer's reading, or why there is none.
    pub baro: Option<Result<BaroSample, SensorError>>,
}

/// The sensor bus's schedule.
pub struct Reads {
    imu: bmi088::SampleReader,
    baro: Option<bmp388::SampleReader>,
    samples: u32,
}

impl Reads {
    /// Idle; the barometer is read only if it started (its calibration).
    pub const fn new(baro: Option<Calibration>) -> Self {
        Self {
            imu: bmi088::SampleReader::new(),
            baro: match baro {
                Some(cal) => Some(bmp388::SampleReader::new(cal)),
                None => None,
            },
            samples: 0,
        }
    }

    /// A transfer on the bus.
    pub fn busy(&self) -> bool {
        self.imu.busy() || self.baro.as_ref().is_some_and(|b| b.busy())
    }

    /// The gyroscope's data-ready: abandons what is still on the bus (and
    /// reports it) and starts the IMU sample (a refusal is this sample,
    /// missing).
    pub fn data_ready<R: Regs>(&mut self, r: &R) -> Finished {
        let mut f = Finished::default();
        if let Some(b) = self.baro.as_mut().filter(|b| b.busy()) {
            b.abort(r);
            f.baro = Some(Err(SensorError::Timeout {
                device: "BMP388 (reading still on the bus at the next data-ready)",
                polls: 0,
            }));
        }
        if let Err(e) = self.imu.data_ready(r) {
            f.imu = Some(Err(e));
        }
        f
    }

    /// The I2C event (`error` false) or error interrupt.
    pub fn on_interrupt<R: Regs>(&mut self, r: &R, error: bool) -> Finished {
        let mut f = Finished::default();
        if let Some(b) = self.baro.as_mut().filter(|b| b.busy()) {
            f.baro = if error { b.on_error(r) } else { b.on_event(r) };
            return f;
        }
        // The IMU's (or a stray event, which its idle burst quiets).
        f.imu = if error {
            self.imu.on_error(r)
        } else {
            self.imu.on_event(r)
        };
        if f.imu.is_some() {
            self.samples = self.samples.wrapping_add(1);
            if let Some(b) = self.baro.as_mut().filter(|_| self.samples.is_multiple_of(BARO_EVERY)) {
                if let Err(e) = b.start(r) {
                    f.baro = Some(Err(e));
                }
            }
        }
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::i2c::I2cMaster;
    use crate::i2c_model::{part, Bus};
    use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource};

    /// The gyroscope, accelerometer and barometer on the modelled bus; the
    /// barometer's DATA is the reading from `bmp388`'s tests (100 876.006
    /// Pa, 30.4993 °C with that part's calibration).
    const NVM: [u8; 21] = [
        0x23, 0x6B, 0x58, 0x49, 0xF6, 0x5C, 0xFF, 0xCE, 0xF4, 0x23, 0x00, 0xEA, 0x63, 0x6E, 0x79, 0xF3, 0xF6, 0xAA,
        0x43, 0x12, 0xC4,
    ];

    fn bus() -> Bus {
        let mut gyro = part(0x69, 0x0F);
        let mut acc = part(0x18, 0x1E);
        let mut baro = part(0x77, 0x50);
        gyro.regs[0x02..0x08].copy_from_slice(&[100, 0, 0, 0, 0, 0]);
        acc.regs[0x12..0x18].copy_from_slice(&[0, 0, 0, 0, 0x55, 0x05]);
        baro.regs[0x04..0x0A].copy_from_slice(&[151, 159, 109, 115, 216, 133]);
        let bus = Bus::new(vec![gyro, acc, baro]);
        bus.0.borrow_mut().stop_lag = 20;
        bus
    }

    /// A new gyroscope sample on the part (the same one ten times is a
    /// frozen part).
    fn fresh(bus: &Bus) {
        let mut s = bus.0.borrow_mut();
        s.parts[0].regs[0x03] = s.parts[0].regs[0x03].wrapping_add(1);
    }

    /// One data-ready and its interrupts until the bus is idle: what each
    /// finished, and how many interrupts it took.
    fn period(rd: &mut Reads, bus: &Bus) -> (Vec<Finished>, usize) {
        fresh(bus);
        let mut done = vec![rd.data_ready(&bus)];
        let mut irqs = 0;
        while rd.busy() {
            let error = bus.error_pending();
            assert!(error || bus.event_pending(), "a transfer with no interrupt pending");
            done.push(rd.on_interrupt(&bus, error));
            irqs += 1;
            assert!(irqs < 100, "never ended");
        }
        (done.into_iter().filter(|f| *f != Finished::default()).collect(), irqs)
    }

    #[test]
    fn every_20th_sample_brings_the_barometer_after_the_imu() {
        let bus = bus();
        let _m = I2cMaster::new(&bus);
        let mut rd = Reads::new(Some(Calibration::from_nvm(&NVM)));
        let mut baro = Vec::new();
        for k in 1..=60u32 {
            let (done, irqs) = period(&mut rd, &bus);
            let imu = done.iter().find_map(|f| f.imu).expect("an IMU sample every period");
            assert!(imu.is_ok(), "{k}: {imu:?}");
            // The IMU sample is handed on before the barometer's read ends.
            assert!(done[0].imu.is_some());
            if let Some(b) = done.iter().find_map(|f| f.baro) {
                baro.push(k);
                let b = b.unwrap();
                assert!((b.pressure_pa - 100_876.01).abs() < 0.02, "{b:?}");
                assert_eq!(irqs, 2 * 11 + 11, "{k}");
            } else {
                assert_eq!(irqs, 2 * 11, "{k}: two bursts of 6 bytes, 11 interrupts each");
            }
        }
        assert_eq!(baro, [20, 40, 60]);
        // No barometer (it did not start): the IMU alone.
        let mut rd = Reads::new(None);
        for _ in 0..20 {
            assert_eq!(period(&mut rd, &bus).1, 22);
        }
    }

    #[test]
    fn a_barometer_still_reading_at_the_next_data_ready_is_abandoned_not_the_imu() {
        let bus = bus();
        let _m = I2cMaster::new(&bus);
        let mut rd = Reads::new(Some(Calibration::from_nvm(&NVM)));
        for _ in 0..19 {
            period(&mut rd, &bus);
        }
        // The 20th sample, then the barometer's read cut short by the next data-ready.
        fresh(&bus);
        rd.data_ready(&&bus);
        let mut f = Finished::default();
        while f.imu.is_none() {
            f = rd.on_interrupt(&&bus, bus.error_pending());
        }
        assert!(rd.busy() && f.baro.is_none(), "the barometer's read started");
        rd.on_interrupt(&&bus, false);
        fresh(&bus);
        let late = rd.data_ready(&&bus);
        assert!(matches!(late.baro, Some(Err(SensorError::Timeout { .. }))), "{late:?}");
        assert_eq!(late.imu, None, "the IMU sample started");
        let mut f = Finished::default();
        while f.imu.is_none() {
            f = rd.on_interrupt(&&bus, bus.error_pending());
        }
        assert!(f.imu.unwrap().is_ok());
    }

    #[test]
    fn a_barometer_gone_from_the_bus_fails_its_reads_and_the_imu_flies_on() {
        let bus = bus();
        let _m = I2cMaster::new(&bus);
        bus.0.borrow_mut().parts.truncate(2);
        let mut rd = Reads::new(Some(Calibration::from_nvm(&NVM)));
        let mut failed = 0;
        for _ in 0..40 {
            let (done, _) = period(&mut rd, &bus);
            assert!(done.iter().find_map(|f| f.imu).unwrap().is_ok());
            if let Some(b) = done.iter().find_map(|f| f.baro) {
                assert_eq!(
                    b,
                    Err(SensorError::Bus {
                        device: "BMP388",
                        kind: ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)
                    })
                );
                failed += 1;
            }
        }
        assert_eq!(failed, 2);
    }
}
