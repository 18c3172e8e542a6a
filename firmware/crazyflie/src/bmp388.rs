//! Bosch BMP388 barometer over I2C (address 0x77, chip id 0x50),
//! configured as the Crazyflie firmware configures it: pressure ×8
//! oversampling, temperature ×1, IIR coefficient 3, 50 Hz in normal mode.
//! Compensation is the datasheet's floating-point one (BST-BMP388-DS001
//! §9.2, "Trimming coefficients" and the compensation formulas).

use crate::error::{FreezeWatch, SensorError};
use crate::i2c::{Burst, Progress, Regs};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;

/// The I2C address (SDO high, as on the Crazyflie 2.1).
pub const ADDR: u8 = 0x77;
/// `CHIP_ID` (register 0x00).
pub const CHIP_ID: u8 = 0x50;

/// Register addresses (datasheet §4.3).
pub mod reg {
    /// Chip id.
    pub const CHIP_ID: u8 = 0x00;
    /// Error flags (fatal, command, configuration).
    pub const ERR: u8 = 0x02;
    /// Pressure XLSB; 6 bytes: pressure then temperature, 24 bits each, LSB first.
    pub const DATA: u8 = 0x04;
    /// Power control: sensors enabled and mode.
    pub const PWR_CTRL: u8 = 0x1B;
    /// Oversampling.
    pub const OSR: u8 = 0x1C;
    /// Output data rate.
    pub const ODR: u8 = 0x1D;
    /// IIR filter.
    pub const CONFIG: u8 = 0x1F;
    /// First of the 21 calibration bytes (NVM_PAR_T1).
    pub const CALIB: u8 = 0x31;
    /// Command register.
    pub const CMD: u8 = 0x7E;
}

/// The values written.
pub mod val {
    /// `CMD`: soft reset.
    pub const SOFTRESET: u8 = 0xB6;
    /// `OSR`: `osr_p` = ×8 (0b011), `osr_t` = ×1 (0b000 in bits 5–3).
    pub const OSR_P8_T1: u8 = 0x03;
    /// `ODR`: `odr_sel` = 2, 200 Hz / 2² = 50 Hz.
    pub const ODR_50HZ: u8 = 0x02;
    /// `CONFIG`: `iir_filter` = coefficient 3 (0b010 in bits 3–1).
    pub const IIR_3: u8 = 0x04;
    /// `PWR_CTRL`: pressure and temperature on (bits 0, 1), normal mode (0b11 in bits 5–4).
    pub const NORMAL_PT: u8 = 0x33;
}

/// Wait after the soft reset, ms (datasheet: start-up 2 ms).
pub const RESET_MS: u32 = 2;
/// Identical pressure and temperature words in a row taken as frozen: 0.5 s at 50 Hz.
pub const FROZEN_REPEATS: u16 = 25;
/// The datasheet's operating range: 300–1250 hPa, −40–85 °C; outside it a
/// compensated value is not a measurement.
pub const PRESSURE_RANGE_PA: (f32, f32) = (30_000.0, 125_000.0);
/// Operating temperature range, °C.
pub const TEMPERATURE_RANGE_C: (f32, f32) = (-40.0, 85.0);

/// Measurement time of one conversion, µs (datasheet §3.9.2): 234 + pressure
/// (392 + 2^osr_p · 2020) + temperature (163 + 2^osr_t · 2020).
pub const fn conversion_time_us(osr_p_log2: u32, osr_t_log2: u32) -> u32 {
    234 + (392 + (1 << osr_p_log2) * 2020) + (163 + (1 << osr_t_log2) * 2020)
}

/// The trimming coefficients, already scaled (datasheet §9.1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    t: [f64; 3],
    p: [f64; 11],
}

/// `2^e` as f64, for the datasheet's scale factors.
fn pow2(e: i32) -> f64 {
    libm::ldexp(1.0, e)
}

impl Calibration {
    /// From the 21 NVM bytes at 0x31 (PAR_T1 u16, T2 u16, T3 i8, P1 i16,
    /// P2 i16, P3 i8, P4 i8, P5 u16, P6 u16, P7 i8, P8 i8, P9 i16, P10 i8,
    /// P11 i8; little-endian).
    pub fn from_nvm(b: &[u8; 21]) -> Self {
        let u16_at = |i: usize| f64::from(u16::from_le_bytes([b[i], b[i + 1]]));
        let i16_at = |i: usize| f64::from(i16::from_le_bytes([b[i], b[i + 1]]));
        let i8_at = |i: usize| f64::from(b[i] as i8);
        Self {
            t: [u16_at(0) / pow2(-8), u16_at(2) / pow2(30), i8_at(4) / pow2(48)],
            p: [
                (i16_at(5) - pow2(14)) / pow2(20),
                (i16_at(7) - pow2(14)) / pow2(29),
                i8_at(9) / pow2(32),
                i8_at(10) / pow2(37),
                u16_at(11) / pow2(-3),
                u16_at(13) / pow2(6),
                i8_at(15) / pow2(8),
                i8_at(16) / pow2(15),
                i16_at(17) / pow2(48),
                i8_at(19) / pow2(48),
                i8_at(20) / pow2(65),
            ],
        }
    }

    /// Compensated (pressure Pa, temperature °C) of the raw 24-bit words.
    pub fn compensate(&self, raw_p: u32, raw_t: u32) -> (f64, f64) {
        let [t1, t2, t3] = self.t;
        let d = f64::from(raw_t) - t1;
        let t = d * t2 + d * d * t3;
        let [p1, p2, p3, p4, p5, p6, p7, p8, p9, p10, p11] = self.p;
        let (t_2, t_3) = (t * t, t * t * t);
        let out1 = p5 + p6 * t + p7 * t_2 + p8 * t_3;
        let up = f64::from(raw_p);
        let out2 = up * (p1 + p2 * t + p3 * t_2 + p4 * t_3);
        let out3 = up * up * (p9 + p10 * t) + up * up * up * p11;
        (out1 + out2 + out3, t)
    }
}

/// One barometer sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaroSample {
    /// Static pressure, Pa.
    pub pressure_pa: f32,
    /// Die temperature, °C.
    pub temperature_c: f32,
}

/// The compensated sample of the six `DATA` bytes (pressure then
/// temperature, 24 bits each, LSB first); values outside the part's range
/// are refused.
fn convert(cal: &Calibration, b: &[u8; 6]) -> Result<BaroSample, SensorError> {
    let raw_p = u32::from_le_bytes([b[0], b[1], b[2], 0]);
    let raw_t = u32::from_le_bytes([b[3], b[4], b[5], 0]);
    let (p, t) = cal.compensate(raw_p, raw_t);
    let within = |v: f64, (lo, hi): (f32, f32)| v >= f64::from(lo) && v <= f64::from(hi);
    if !within(t, TEMPERATURE_RANGE_C) {
        return Err(SensorError::Implausible {
            device: DEV,
            quantity: "temperature (°C)",
        });
    }
    if !within(p, PRESSURE_RANGE_PA) {
        return Err(SensorError::Implausible {
            device: DEV,
            quantity: "pressure (Pa)",
        });
    }
    Ok(BaroSample {
        pressure_pa: p as f32,
        temperature_c: t as f32,
    })
}

/// The BMP388 on an I2C bus.
pub struct Bmp388<I> {
    i2c: I,
    cal: Option<Calibration>,
    freeze: FreezeWatch<6>,
}

const DEV: &str = "BMP388";

impl<I: I2c> Bmp388<I> {
    /// The driver on `i2c`; nothing is sent until [`Bmp388::init`].
    pub fn new(i2c: I) -> Self {
        Self {
            i2c,
            cal: None,
            freeze: FreezeWatch::new(FROZEN_REPEATS),
        }
    }

    /// Gives the bus back.
    pub fn release(self) -> I {
        self.i2c
    }

    /// The part's calibration, once [`Bmp388::init`] read it (for
    /// [`SampleReader`]).
    pub fn calibration(&self) -> Option<Calibration> {
        self.cal
    }

    fn read(&mut self, r: u8, buf: &mut [u8]) -> Result<(), SensorError> {
        self.i2c
            .write_read(ADDR, &[r], buf)
            .map_err(|e| SensorError::bus(DEV, e))
    }

    fn write(&mut self, r: u8, v: u8) -> Result<(), SensorError> {
        self.i2c.write(ADDR, &[r, v]).map_err(|e| SensorError::bus(DEV, e))
    }

    fn no_errors(&mut self) -> Result<(), SensorError> {
        let mut e = [0u8];
        self.read(reg::ERR, &mut e)?;
        if e[0] & 0x07 == 0 {
            Ok(())
        } else {
            Err(SensorError::DeviceError {
                device: DEV,
                flags: e[0],
            })
        }
    }

    /// Checks the chip id, soft-resets, reads the calibration, writes the
    /// configuration in sleep mode, then starts normal mode and checks the
    /// error register (a configuration the part refuses sets `conf_err`).
    pub fn init(&mut self, delay: &mut impl DelayNs) -> Result<(), SensorError> {
        let mut id = [0u8];
        self.read(reg::CHIP_ID, &mut id)?;
        if id[0] != CHIP_ID {
            return Err(SensorError::ChipId {
                device: DEV,
                expected: CHIP_ID,
                found: id[0],
            });
        }
        self.write(reg::CMD, val::SOFTRESET)?;
        delay.delay_ms(RESET_MS);
        self.no_errors()?;
        let mut nvm = [0u8; 21];
        self.read(reg::CALIB, &mut nvm)?;
        self.write(reg::OSR, val::OSR_P8_T1)?;
        self.write(reg::ODR, val::ODR_50HZ)?;
        self.write(reg::CONFIG, val::IIR_3)?;
        self.write(reg::PWR_CTRL, val::NORMAL_PT)?;
        self.no_errors()?;
        self.cal = Some(Calibration::from_nvm(&nvm));
        self.freeze = FreezeWatch::new(FROZEN_REPEATS);
        Ok(())
    }

    /// One compensated sample (a 6-byte burst read); refuses values outside
    /// the part's range and a frozen part. Before [`Bmp388::init`] it is an
    /// error, not a guess.
    pub fn sample(&mut self) -> Result<BaroSample, SensorError> {
        let cal = self.cal.ok_or(SensorError::Implausible {
            device: DEV,
            quantity: "sample before calibration was read",
        })?;
        let mut b = [0u8; 6];
        self.read(reg::DATA, &mut b)?;
        self.freeze.check(DEV, &b)?;
        convert(&cal, &b)
    }
}

/// The barometer's sample read on the bus's interrupts (a [`Burst`] of the
/// six `DATA` bytes), compensated with the part's calibration, with the
/// same range and freeze checks as [`Bmp388::sample`]. The Crazyflie's
/// sensor bus runs it after an IMU sample ([`crate::reads::Reads`]).
pub struct SampleReader {
    burst: Burst,
    cal: Calibration,
    freeze: FreezeWatch<6>,
}

impl SampleReader {
    /// Idle, with the part's calibration ([`Bmp388::calibration`]).
    pub const fn new(cal: Calibration) -> Self {
        Self {
            burst: Burst::new(),
            cal,
            freeze: FreezeWatch::new(FROZEN_REPEATS),
        }
    }

    /// Starts a sample's read.
    pub fn start<R: Regs>(&mut self, r: &R) -> Result<(), SensorError> {
        self.burst
            .start(r, ADDR, reg::DATA, 6)
            .map_err(|e| SensorError::of_burst(DEV, e))
    }

    /// A sample under way.
    pub fn busy(&self) -> bool {
        self.burst.busy()
    }

    /// Abandons the sample under way (its owner's bound).
    pub fn abort<R: Regs>(&mut self, r: &R) {
        self.burst.abort(r);
    }

    fn advance(&mut self, p: Progress) -> Option<Result<BaroSample, SensorError>> {
        match p {
            Progress::Pending => None,
            Progress::Failed(e) => Some(Err(SensorError::of_burst(DEV, e))),
            Progress::Done => {
                let mut b = [0u8; 6];
                b.copy_from_slice(self.burst.data());
                Some(self.freeze.check(DEV, &b).and_then(|()| convert(&self.cal, &b)))
            }
        }
    }

    /// The I2C event interrupt: `Some` once the sample is read (or failed).
    pub fn on_event<R: Regs>(&mut self, r: &R) -> Option<Result<BaroSample, SensorError>> {
        let p = self.burst.on_event(r);
        self.advance(p)
    }

    /// The I2C error interrupt: `Some(Err)` if it ended the sample.
    pub fn on_error<R: Regs>(&mut self, r: &R) -> Option<Result<BaroSample, SensorError>> {
        let p = self.burst.on_error(r);
        self.advance(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource};
    use embedded_hal_mock::eh1::delay::{CheckedDelay, NoopDelay, Transaction as D};
    use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};

    /// A real part's NVM and one raw reading with their compensated values,
    /// from elixir-sensors/bmp3xx's tests (an independent implementation of
    /// the same datasheet formulas, checked there against the part):
    /// calibration 0x236B5849F65CFFCEF42300EA636E79F3F6AA4312C4, data
    /// <<151, 159, 109, 115, 216, 133>> → 100 876.006 Pa, 30.4993 °C.
    const NVM: [u8; 21] = [
        0x23, 0x6B, 0x58, 0x49, 0xF6, 0x5C, 0xFF, 0xCE, 0xF4, 0x23, 0x00, 0xEA, 0x63, 0x6E, 0x79, 0xF3, 0xF6, 0xAA,
        0x43, 0x12, 0xC4,
    ];
    const DATA: [u8; 6] = [151, 159, 109, 115, 216, 133];

    #[test]
    fn compensation_matches_an_independent_implementation_on_a_real_parts_values() {
        let cal = Calibration::from_nvm(&NVM);
        let raw_p = u32::from_le_bytes([DATA[0], DATA[1], DATA[2], 0]);
        let raw_t = u32::from_le_bytes([DATA[3], DATA[4], DATA[5], 0]);
        let (p, t) = cal.compensate(raw_p, raw_t);
        assert!((p - 100_876.006_346_921_99).abs() < 1e-4, "{p}");
        assert!((t - 30.499_314_453_874_284).abs() < 1e-6, "{t}");
        // The unscaled coefficients the same test lists (par_t1 27 427 …, par_p11 −60).
        assert_eq!(cal.t[0], 27_427.0 * 256.0);
        assert_eq!(cal.p[4], 25_578.0 * 8.0);
        assert_eq!(cal.p[10], -60.0 / pow2(65));
    }

    #[test]
    fn the_chosen_rate_leaves_time_for_the_conversion() {
        // ×8 pressure, ×1 temperature: 18.969 ms, inside the 20 ms of 50 Hz.
        assert_eq!(conversion_time_us(3, 0), 18_969);
        assert!(conversion_time_us(3, 0) < 20_000);
        // ×16 would not fit (the part would flag conf_err).
        assert!(conversion_time_us(4, 0) > 20_000);
    }

    fn power_up() -> Vec<T> {
        vec![
            T::write_read(0x77, vec![0x00], vec![0x50]),
            T::write(0x77, vec![0x7E, 0xB6]),
            T::write_read(0x77, vec![0x02], vec![0x00]),
            T::write_read(0x77, vec![0x31], NVM.to_vec()),
            T::write(0x77, vec![0x1C, 0x03]),
            T::write(0x77, vec![0x1D, 0x02]),
            T::write(0x77, vec![0x1F, 0x04]),
            T::write(0x77, vec![0x1B, 0x33]),
            T::write_read(0x77, vec![0x02], vec![0x00]),
        ]
    }

    #[test]
    fn power_up_and_a_sample_follow_the_datasheet_transcript() {
        let mut t = power_up();
        t.push(T::write_read(0x77, vec![0x04], DATA.to_vec()));
        let mut i2c = Mock::new(&t);
        let mut delay = CheckedDelay::new(&[D::delay_ms(2)]);
        let mut baro = Bmp388::new(i2c.clone());
        assert_eq!(baro.init(&mut delay), Ok(()));
        let s = baro.sample().unwrap();
        assert!((s.pressure_pa - 100_876.01).abs() < 0.02);
        assert!((s.temperature_c - 30.4993).abs() < 1e-3);
        i2c.done();
        delay.done();
    }

    #[test]
    fn a_bmp390_a_nack_and_a_refused_configuration_are_errors_by_name() {
        // A BMP390 (chip id 0x60) answers: refused, nothing written.
        let mut i2c = Mock::new(&[T::write_read(0x77, vec![0x00], vec![0x60])]);
        let e = Bmp388::new(i2c.clone()).init(&mut NoopDelay).unwrap_err();
        assert_eq!(e.to_string(), "BMP388: chip id 0x60, expected 0x50");
        i2c.done();
        // Nothing at 0x77.
        let nack = ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address);
        let mut i2c = Mock::new(&[T::write_read(0x77, vec![0x00], vec![0]).with_error(nack)]);
        let e = Bmp388::new(i2c.clone()).init(&mut NoopDelay).unwrap_err();
        assert_eq!(
            e,
            SensorError::Bus {
                device: "BMP388",
                kind: nack
            }
        );
        i2c.done();
        // conf_err (bit 2) after normal mode.
        let mut t = power_up();
        *t.last_mut().unwrap() = T::write_read(0x77, vec![0x02], vec![0x04]);
        let mut i2c = Mock::new(&t);
        let e = Bmp388::new(i2c.clone()).init(&mut NoopDelay).unwrap_err();
        assert_eq!(e.to_string(), "BMP388: error flags 0x04");
        i2c.done();
    }

    #[test]
    fn samples_outside_the_parts_range_and_a_frozen_part_are_refused() {
        let mut t = power_up();
        // All ones: the compensated pressure is far outside 300–1250 hPa.
        t.push(T::write_read(0x77, vec![0x04], vec![0xFF, 0xFF, 0xFF, 115, 216, 133]));
        for _ in 0..=FROZEN_REPEATS {
            t.push(T::write_read(0x77, vec![0x04], DATA.to_vec()));
        }
        let mut i2c = Mock::new(&t);
        let mut baro = Bmp388::new(i2c.clone());
        baro.init(&mut NoopDelay).unwrap();
        assert_eq!(
            baro.sample(),
            Err(SensorError::Implausible {
                device: "BMP388",
                quantity: "pressure (Pa)"
            })
        );
        for _ in 0..FROZEN_REPEATS {
            assert!(baro.sample().is_ok());
        }
        assert_eq!(
            baro.sample(),
            Err(SensorError::Frozen {
                device: "BMP388",
                repeats: FROZEN_REPEATS
            })
        );
        i2c.done();
    }

    #[test]
    fn a_sample_before_init_is_an_error_and_touches_no_bus() {
        let mut i2c = Mock::new(&[]);
        assert!(matches!(
            Bmp388::new(i2c.clone()).sample(),
            Err(SensorError::Implausible { .. })
        ));
        i2c.done();
    }
}
