//! Bosch BMI088 (accelerometer + gyroscope) over I2C, configured as the
//! Crazyflie firmware configures it (`sensors_bmi088_bmp3xx.c`):
//!
//! | part | address | chip id | range | rate and filter |
//! |---|---|---|---|---|
//! | gyroscope | 0x69 | 0x0F | ±2000 °/s | ODR 1000 Hz, 116 Hz bandwidth |
//! | accelerometer | 0x18 | 0x1E | ±24 g | ODR 1600 Hz, OSR4 |
//!
//! The gyroscope's data-ready interrupt goes to INT3 (push-pull, active
//! high), wired to PC14: the board's 1 kHz tick. Registers, reset values and
//! the power-up sequence are the BMI088 datasheet's (BST-BMI088-DS001 §5–6):
//! after power-on the gyroscope is in normal mode and the accelerometer in
//! suspend; [`Bmi088::init`] soft-resets both (1 ms and 30 ms waits), powers
//! the accelerometer on (`ACC_PWR_CTRL` = 4, ≥ 450 µs) and active
//! (`ACC_PWR_CONF` = 0), writes the ranges, rates and interrupt, and reads
//! the measurement configuration back.
//!
//! The sensor's axes are the Crazyflie's body axes (x forward, y left, z
//! up); [`Bmi088::read`] returns body FRD (x forward, y right, z down): y and
//! z change sign.

use crate::error::{FreezeWatch, SensorError};
use crate::i2c::{Burst, I2cError, Progress, Regs};
use embedded_hal::delay::DelayNs;
use embedded_hal::i2c::I2c;

/// The accelerometer's I2C address (SDO1 low, as on the Crazyflie 2.1).
pub const ACCEL_ADDR: u8 = 0x18;
/// The gyroscope's I2C address (SDO2 high, as on the Crazyflie 2.1).
pub const GYRO_ADDR: u8 = 0x69;
/// `ACC_CHIP_ID` (register 0x00).
pub const ACCEL_CHIP_ID: u8 = 0x1E;
/// `GYRO_CHIP_ID` (register 0x00).
pub const GYRO_CHIP_ID: u8 = 0x0F;

/// Register addresses (datasheet §5.3 and §5.5).
pub mod reg {
    /// Chip id, both parts.
    pub const CHIP_ID: u8 = 0x00;
    /// Accelerometer error flags (`ACC_ERR_REG`).
    pub const ACC_ERR: u8 = 0x02;
    /// Accelerometer data, x LSB first (6 bytes).
    pub const ACC_X_LSB: u8 = 0x12;
    /// Accelerometer bandwidth (OSR) and output rate.
    pub const ACC_CONF: u8 = 0x40;
    /// Accelerometer range.
    pub const ACC_RANGE: u8 = 0x41;
    /// Accelerometer power configuration (active / suspend).
    pub const ACC_PWR_CONF: u8 = 0x7C;
    /// Accelerometer power control (on / off).
    pub const ACC_PWR_CTRL: u8 = 0x7D;
    /// Accelerometer soft reset.
    pub const ACC_SOFTRESET: u8 = 0x7E;
    /// Gyroscope data, x LSB first (6 bytes).
    pub const GYRO_X_LSB: u8 = 0x02;
    /// Gyroscope range.
    pub const GYRO_RANGE: u8 = 0x0F;
    /// Gyroscope output rate and filter bandwidth.
    pub const GYRO_BANDWIDTH: u8 = 0x10;
    /// Gyroscope power mode.
    pub const GYRO_LPM1: u8 = 0x11;
    /// Gyroscope soft reset.
    pub const GYRO_SOFTRESET: u8 = 0x14;
    /// Gyroscope new-data interrupt enable.
    pub const GYRO_INT_CTRL: u8 = 0x15;
    /// INT3/INT4 pin configuration (level, open drain).
    pub const INT3_INT4_IO_CONF: u8 = 0x16;
    /// INT3/INT4 interrupt mapping.
    pub const INT3_INT4_IO_MAP: u8 = 0x18;
}

/// The values written (datasheet register tables; the Crazyflie's choices).
pub mod val {
    /// Soft reset command, both parts.
    pub const SOFTRESET: u8 = 0xB6;
    /// `ACC_PWR_CTRL`: accelerometer on.
    pub const ACC_ENABLE: u8 = 0x04;
    /// `ACC_PWR_CONF`: active mode.
    pub const ACC_ACTIVE: u8 = 0x00;
    /// `ACC_CONF`: `acc_bwp` = 0x8 (OSR4) in bits 7–4, `acc_odr` = 0xC (1600 Hz).
    pub const ACC_CONF_OSR4_1600HZ: u8 = 0x8C;
    /// `ACC_RANGE`: ±24 g.
    pub const ACC_RANGE_24G: u8 = 0x03;
    /// `GYRO_RANGE`: ±2000 °/s.
    pub const GYRO_RANGE_2000DPS: u8 = 0x00;
    /// `GYRO_BANDWIDTH`: ODR 1000 Hz, filter 116 Hz (bit 7 reads as 1).
    pub const GYRO_BW_1000HZ_116HZ: u8 = 0x02;
    /// `GYRO_LPM1`: normal mode.
    pub const GYRO_NORMAL: u8 = 0x00;
    /// `GYRO_INT_CTRL`: new-data interrupt on.
    pub const GYRO_DRDY_ON: u8 = 0x80;
    /// `INT3_INT4_IO_CONF` bits for INT3: level (bit 0, 1 = active high) and
    /// open drain (bit 1, 0 = push-pull).
    pub const INT3_LVL: u8 = 0x01;
    /// INT3's open-drain bit.
    pub const INT3_OD: u8 = 0x02;
    /// `INT3_INT4_IO_MAP`: data ready → INT3.
    pub const MAP_DRDY_INT3: u8 = 0x01;
}

/// Waits of the power-up sequence, ms (datasheet §4.6, §5.3.11, §5.5.9).
pub mod wait {
    /// After the accelerometer's soft reset.
    pub const ACC_RESET_MS: u32 = 1;
    /// After `ACC_PWR_CTRL` (datasheet: ≥ 450 µs; the official driver waits 5 ms).
    pub const ACC_POWER_MS: u32 = 5;
    /// After `ACC_PWR_CONF` (a write in suspend mode needs 1 ms before the next).
    pub const ACC_ACTIVE_MS: u32 = 1;
    /// After the gyroscope's soft reset.
    pub const GYRO_RESET_MS: u32 = 30;
}

/// ±24 g over the i16 range: m/s² per LSB (datasheet §5.3.4: g = raw/32768 · 2^(range+1) · 1.5).
pub const ACCEL_MPS2_PER_LSB: f32 = 24.0 * 9.806_65 / 32_768.0;
/// ±2000 °/s over the i16 range: rad/s per LSB.
pub const GYRO_RADPS_PER_LSB: f32 = 2000.0 / 32_768.0 * (core::f32::consts::PI / 180.0);

/// Identical 12-byte samples in a row taken as a frozen sensor: 10 ms at
/// 1 kHz. With the noise of the datasheet (gyro 0.014 °/s/√Hz over 116 Hz ≈
/// 2.5 LSB rms per axis; accel 175 µg/√Hz ≈ 4 LSB rms) a live part repeats
/// all six words even twice in a row with a probability below 1e-6.
pub const FROZEN_REPEATS: u16 = 10;

/// One IMU sample in body FRD.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Angular rate, body FRD, rad/s.
    pub gyro_frd_radps: [f32; 3],
    /// Specific force, body FRD, m/s² (at rest: z ≈ −9.81).
    pub accel_frd_mps2: [f32; 3],
}

/// The BMI088 on an I2C bus.
pub struct Bmi088<I> {
    i2c: I,
    freeze: FreezeWatch<12>,
}

const ACC: &str = "BMI088 accelerometer";
const GYRO: &str = "BMI088 gyroscope";

impl<I: I2c> Bmi088<I> {
    /// The driver on `i2c`; nothing is sent until [`Bmi088::init`].
    pub fn new(i2c: I) -> Self {
        Self {
            i2c,
            freeze: FreezeWatch::new(FROZEN_REPEATS),
        }
    }

    /// Gives the bus back.
    pub fn release(self) -> I {
        self.i2c
    }

    fn read_reg(&mut self, dev: &'static str, addr: u8, r: u8) -> Result<u8, SensorError> {
        let mut b = [0u8];
        self.i2c
            .write_read(addr, &[r], &mut b)
            .map_err(|e| SensorError::bus(dev, e))?;
        Ok(b[0])
    }

    fn write_reg(&mut self, dev: &'static str, addr: u8, r: u8, v: u8) -> Result<(), SensorError> {
        self.i2c.write(addr, &[r, v]).map_err(|e| SensorError::bus(dev, e))
    }

    fn check_id(&mut self, dev: &'static str, addr: u8, expected: u8) -> Result<(), SensorError> {
        let found = self.read_reg(dev, addr, reg::CHIP_ID)?;
        if found == expected {
            Ok(())
        } else {
            Err(SensorError::ChipId {
                device: dev,
                expected,
                found,
            })
        }
    }

    fn check_read_back(&mut self, dev: &'static str, addr: u8, r: u8, wrote: u8, mask: u8) -> Result<(), SensorError> {
        let read = self.read_reg(dev, addr, r)?;
        if read & mask == wrote & mask {
            Ok(())
        } else {
            Err(SensorError::Config {
                device: dev,
                register: r,
                wrote,
                read,
            })
        }
    }

    /// Checks both chip ids and runs the power-up sequence; the first step
    /// that fails is returned and the part stays as it was left.
    pub fn init(&mut self, delay: &mut impl DelayNs) -> Result<(), SensorError> {
        // Gyroscope: it answers in normal mode from power-on.
        self.check_id(GYRO, GYRO_ADDR, GYRO_CHIP_ID)?;
        self.write_reg(GYRO, GYRO_ADDR, reg::GYRO_SOFTRESET, val::SOFTRESET)?;
        delay.delay_ms(wait::GYRO_RESET_MS);
        self.write_reg(GYRO, GYRO_ADDR, reg::GYRO_RANGE, val::GYRO_RANGE_2000DPS)?;
        self.write_reg(GYRO, GYRO_ADDR, reg::GYRO_BANDWIDTH, val::GYRO_BW_1000HZ_116HZ)?;
        self.write_reg(GYRO, GYRO_ADDR, reg::GYRO_LPM1, val::GYRO_NORMAL)?;
        self.write_reg(GYRO, GYRO_ADDR, reg::GYRO_INT_CTRL, val::GYRO_DRDY_ON)?;
        let io = self.read_reg(GYRO, GYRO_ADDR, reg::INT3_INT4_IO_CONF)?;
        let io = (io & !(val::INT3_LVL | val::INT3_OD)) | val::INT3_LVL;
        self.write_reg(GYRO, GYRO_ADDR, reg::INT3_INT4_IO_CONF, io)?;
        self.write_reg(GYRO, GYRO_ADDR, reg::INT3_INT4_IO_MAP, val::MAP_DRDY_INT3)?;
        self.check_read_back(GYRO, GYRO_ADDR, reg::GYRO_RANGE, val::GYRO_RANGE_2000DPS, 0x07)?;
        self.check_read_back(GYRO, GYRO_ADDR, reg::GYRO_BANDWIDTH, val::GYRO_BW_1000HZ_116HZ, 0x0F)?;

        // Accelerometer: soft reset, then on and active, then configured.
        self.check_id(ACC, ACCEL_ADDR, ACCEL_CHIP_ID)?;
        self.write_reg(ACC, ACCEL_ADDR, reg::ACC_SOFTRESET, val::SOFTRESET)?;
        delay.delay_ms(wait::ACC_RESET_MS);
        self.write_reg(ACC, ACCEL_ADDR, reg::ACC_PWR_CTRL, val::ACC_ENABLE)?;
        delay.delay_ms(wait::ACC_POWER_MS);
        self.write_reg(ACC, ACCEL_ADDR, reg::ACC_PWR_CONF, val::ACC_ACTIVE)?;
        delay.delay_ms(wait::ACC_ACTIVE_MS);
        self.write_reg(ACC, ACCEL_ADDR, reg::ACC_CONF, val::ACC_CONF_OSR4_1600HZ)?;
        self.write_reg(ACC, ACCEL_ADDR, reg::ACC_RANGE, val::ACC_RANGE_24G)?;
        self.check_read_back(ACC, ACCEL_ADDR, reg::ACC_CONF, val::ACC_CONF_OSR4_1600HZ, 0xFF)?;
        self.check_read_back(ACC, ACCEL_ADDR, reg::ACC_RANGE, val::ACC_RANGE_24G, 0x03)?;
        let flags = self.read_reg(ACC, ACCEL_ADDR, reg::ACC_ERR)?;
        if flags != 0 {
            return Err(SensorError::DeviceError { device: ACC, flags });
        }
        self.freeze = FreezeWatch::new(FROZEN_REPEATS);
        Ok(())
    }

    /// One sample: two 6-byte burst reads (gyroscope first: its data-ready
    /// is the tick), scaled and turned to body FRD. A frozen pair of
    /// readings ([`FROZEN_REPEATS`] identical) is an error.
    pub fn read(&mut self) -> Result<ImuSample, SensorError> {
        let mut raw = [0u8; 12];
        let (g, a) = raw.split_at_mut(6);
        self.i2c
            .write_read(GYRO_ADDR, &[reg::GYRO_X_LSB], g)
            .map_err(|e| SensorError::bus(GYRO, e))?;
        self.i2c
            .write_read(ACCEL_ADDR, &[reg::ACC_X_LSB], a)
            .map_err(|e| SensorError::bus(ACC, e))?;
        self.freeze.check("BMI088", &raw)?;
        Ok(sample_from_raw(&raw))
    }
}

/// Scales the raw words (gyro x, y, z then accel x, y, z, little-endian
/// i16, sensor axes FLU) to a body-FRD sample.
pub fn sample_from_raw(raw: &[u8; 12]) -> ImuSample {
    let w = |i: usize| f32::from(i16::from_le_bytes([raw[2 * i], raw[2 * i + 1]]));
    let flu_to_frd = |v: [f32; 3]| [v[0], -v[1], -v[2]];
    ImuSample {
        gyro_frd_radps: flu_to_frd([w(0), w(1), w(2)].map(|v| v * GYRO_RADPS_PER_LSB)),
        accel_frd_mps2: flu_to_frd([w(3), w(4), w(5)].map(|v| v * ACCEL_MPS2_PER_LSB)),
    }
}

/// The 1 kHz sample on the I2C interrupts: at the gyroscope's data-ready
/// ([`SampleReader::data_ready`]) a [`Burst`] reads its six bytes, then the
/// accelerometer's six; the event and error interrupts advance it
/// ([`SampleReader::on_event`], [`SampleReader::on_error`]) and the last
/// one gives the sample, in body FRD, or why there is none (the bus's
/// error; a frozen part, as [`Bmi088::read`] finds it). A sample still on
/// the bus at the next data-ready is abandoned and reported as timed out:
/// the bound of every read is one sample period.
pub struct SampleReader {
    burst: Burst,
    raw: [u8; 12],
    /// Reading the accelerometer's half.
    second: bool,
    freeze: FreezeWatch<12>,
}

impl Default for SampleReader {
    fn default() -> Self {
        Self::new()
    }
}

/// A failed burst as the driver's error, naming the half it was reading.
fn burst_error(second: bool, e: I2cError) -> SensorError {
    SensorError::of_burst(if second { ACC } else { GYRO }, e)
}

impl SampleReader {
    /// Idle.
    pub const fn new() -> Self {
        Self {
            burst: Burst::new(),
            raw: [0; 12],
            second: false,
            freeze: FreezeWatch::new(FROZEN_REPEATS),
        }
    }

    /// The gyroscope's data-ready: starts the sample's reads. `Err` if the
    /// last sample was still on the bus (abandoned: that sample is missing)
    /// or the bus refused to start.
    pub fn data_ready<R: Regs>(&mut self, r: &R) -> Result<(), SensorError> {
        let late = self.burst.busy();
        if late {
            self.burst.abort(r);
        }
        self.second = false;
        let started = self
            .burst
            .start(r, GYRO_ADDR, reg::GYRO_X_LSB, 6)
            .map_err(|e| burst_error(false, e));
        if late {
            return Err(SensorError::Timeout {
                device: "BMI088 (sample still on the bus at the next data-ready)",
                polls: 0,
            });
        }
        started
    }

    /// A sample under way.
    pub fn busy(&self) -> bool {
        self.burst.busy()
    }

    fn advance<R: Regs>(&mut self, r: &R, p: Progress) -> Option<Result<ImuSample, SensorError>> {
        match p {
            Progress::Pending => None,
            Progress::Failed(e) => Some(Err(burst_error(self.second, e))),
            Progress::Done if !self.second => {
                self.raw[..6].copy_from_slice(self.burst.data());
                self.second = true;
                match self.burst.start(r, ACCEL_ADDR, reg::ACC_X_LSB, 6) {
                    Ok(()) => None,
                    Err(e) => Some(Err(burst_error(true, e))),
                }
            }
            Progress::Done => {
                self.raw[6..].copy_from_slice(self.burst.data());
                Some(
                    self.freeze
                        .check("BMI088", &self.raw)
                        .map(|()| sample_from_raw(&self.raw)),
                )
            }
        }
    }

    /// The I2C event interrupt: `Some` once the sample is read (or failed).
    pub fn on_event<R: Regs>(&mut self, r: &R) -> Option<Result<ImuSample, SensorError>> {
        let p = self.burst.on_event(r);
        self.advance(r, p)
    }

    /// The I2C error interrupt: `Some(Err)` if it ended the sample.
    pub fn on_error<R: Regs>(&mut self, r: &R) -> Option<Result<ImuSample, SensorError>> {
        let p = self.burst.on_error(r);
        self.advance(r, p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource};
    use embedded_hal_mock::eh1::delay::{CheckedDelay, NoopDelay, Transaction as D};
    use embedded_hal_mock::eh1::i2c::{Mock, Transaction as T};

    /// The power-up transcript, written from the datasheet's register map
    /// (BST-BMI088-DS001 tables 5.3 and 5.5) and the official firmware's
    /// configuration, byte for byte. INT3_INT4_IO_CONF reads its reset value
    /// 0x0F; the read-backs return what a part returns (GYRO_BANDWIDTH's bit
    /// 7 reads as 1).
    fn power_up() -> Vec<T> {
        vec![
            T::write_read(0x69, vec![0x00], vec![0x0F]),
            T::write(0x69, vec![0x14, 0xB6]),
            T::write(0x69, vec![0x0F, 0x00]),
            T::write(0x69, vec![0x10, 0x02]),
            T::write(0x69, vec![0x11, 0x00]),
            T::write(0x69, vec![0x15, 0x80]),
            T::write_read(0x69, vec![0x16], vec![0x0F]),
            T::write(0x69, vec![0x16, 0x0D]),
            T::write(0x69, vec![0x18, 0x01]),
            T::write_read(0x69, vec![0x0F], vec![0x00]),
            T::write_read(0x69, vec![0x10], vec![0x82]),
            T::write_read(0x18, vec![0x00], vec![0x1E]),
            T::write(0x18, vec![0x7E, 0xB6]),
            T::write(0x18, vec![0x7D, 0x04]),
            T::write(0x18, vec![0x7C, 0x00]),
            T::write(0x18, vec![0x40, 0x8C]),
            T::write(0x18, vec![0x41, 0x03]),
            T::write_read(0x18, vec![0x40], vec![0x8C]),
            T::write_read(0x18, vec![0x41], vec![0x03]),
            T::write_read(0x18, vec![0x02], vec![0x00]),
        ]
    }

    fn delays() -> Vec<D> {
        vec![D::delay_ms(30), D::delay_ms(1), D::delay_ms(5), D::delay_ms(1)]
    }

    #[test]
    fn power_up_follows_the_datasheet_transcript() {
        let mut i2c = Mock::new(&power_up());
        let mut delay = CheckedDelay::new(&delays());
        let mut imu = Bmi088::new(i2c.clone());
        assert_eq!(imu.init(&mut delay), Ok(()));
        i2c.done();
        delay.done();
    }

    fn sample(gyro: [i16; 3], accel: [i16; 3]) -> Vec<T> {
        let bytes = |v: [i16; 3]| v.iter().flat_map(|w| w.to_le_bytes()).collect::<Vec<u8>>();
        vec![
            T::write_read(0x69, vec![0x02], bytes(gyro)),
            T::write_read(0x18, vec![0x12], bytes(accel)),
        ]
    }

    #[test]
    fn a_sample_is_scaled_and_turned_to_body_frd() {
        // At rest, level: +1 g on the sensor's z (up) is 1365.33 LSB at ±24 g;
        // a roll rate of +100 °/s about x (forward) is 1638.4 LSB at ±2000 °/s.
        let mut i2c = Mock::new(&sample([1638, 0, 820], [0, 0, 1365]));
        let mut imu = Bmi088::new(i2c.clone());
        let s = imu.read().unwrap();
        assert!((s.gyro_frd_radps[0] - 100f32.to_radians()).abs() < 0.001);
        // z up 50 °/s (820 LSB) is z down −50 °/s.
        assert!((s.gyro_frd_radps[2] + 50f32.to_radians()).abs() < 0.002);
        assert_eq!(s.gyro_frd_radps[1], 0.0);
        assert!((s.accel_frd_mps2[2] + 9.806_65).abs() < 0.01, "{:?}", s.accel_frd_mps2);
        // Full scale is the range: i16::MIN is exactly −24 g and −2000 °/s.
        assert_eq!(
            sample_from_raw(&[0, 0x80, 0, 0, 0, 0, 0, 0x80, 0, 0, 0, 0]).accel_frd_mps2[0],
            -24.0 * 9.806_65
        );
        assert_eq!(
            sample_from_raw(&[0, 0x80, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]).gyro_frd_radps[0],
            -2000f32.to_radians()
        );
        i2c.done();
    }

    #[test]
    fn a_missing_gyroscope_is_a_bus_error_and_nothing_else_is_sent() {
        let mut i2c = Mock::new(&[T::write_read(0x69, vec![0x00], vec![0x00])
            .with_error(ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address))]);
        let mut imu = Bmi088::new(i2c.clone());
        let e = imu.init(&mut NoopDelay).unwrap_err();
        assert_eq!(
            e,
            SensorError::Bus {
                device: "BMI088 gyroscope",
                kind: ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)
            }
        );
        assert_eq!(
            e.to_string(),
            "BMI088 gyroscope: I2C transfer failed (The device did not acknowledge its address)"
        );
        i2c.done();
    }

    #[test]
    fn a_wrong_chip_id_is_refused_by_name() {
        // A BMI055 (gyro id 0x0F, accel id 0xFA) on the accelerometer's address.
        let mut t = power_up();
        t.truncate(12);
        t[11] = T::write_read(0x18, vec![0x00], vec![0xFA]);
        let mut i2c = Mock::new(&t);
        let mut imu = Bmi088::new(i2c.clone());
        let e = imu.init(&mut NoopDelay).unwrap_err();
        assert_eq!(e.to_string(), "BMI088 accelerometer: chip id 0xfa, expected 0x1e");
        i2c.done();
    }

    #[test]
    fn a_configuration_that_does_not_read_back_is_refused() {
        // The range write did not take (the part still reports ±3 g, 0x00).
        let mut t = power_up();
        t.truncate(19);
        t[18] = T::write_read(0x18, vec![0x41], vec![0x00]);
        let mut i2c = Mock::new(&t);
        let mut imu = Bmi088::new(i2c.clone());
        let e = imu.init(&mut NoopDelay).unwrap_err();
        assert_eq!(
            e,
            SensorError::Config {
                device: "BMI088 accelerometer",
                register: 0x41,
                wrote: 0x03,
                read: 0x00
            }
        );
        i2c.done();
    }

    #[test]
    fn an_error_flag_after_configuration_is_reported() {
        let mut t = power_up();
        *t.last_mut().unwrap() = T::write_read(0x18, vec![0x02], vec![0x04]);
        let mut i2c = Mock::new(&t);
        let mut imu = Bmi088::new(i2c.clone());
        let e = imu.init(&mut NoopDelay).unwrap_err();
        assert_eq!(e.to_string(), "BMI088 accelerometer: error flags 0x04");
        i2c.done();
    }

    #[test]
    fn a_stuck_bus_fails_the_read_it_happened_in() {
        // The HAL's bounded wait for the bus gave up (ErrorKind::Bus) on the
        // accelerometer half: the sample is an error, the next one is fresh.
        let mut t = vec![
            T::write_read(0x69, vec![0x02], vec![0; 6]),
            T::write_read(0x18, vec![0x12], vec![0; 6]).with_error(ErrorKind::Bus),
        ];
        t.extend(sample([1, 2, 3], [4, 5, 1365]));
        let mut i2c = Mock::new(&t);
        let mut imu = Bmi088::new(i2c.clone());
        assert_eq!(
            imu.read(),
            Err(SensorError::Bus {
                device: "BMI088 accelerometer",
                kind: ErrorKind::Bus
            })
        );
        assert!(imu.read().is_ok());
        i2c.done();
    }

    #[test]
    fn a_frozen_sensor_is_caught_after_the_stated_repeats() {
        let mut t = Vec::new();
        for _ in 0..=FROZEN_REPEATS {
            t.extend(sample([3, -2, 7], [10, -4, 1360]));
        }
        t.extend(sample([4, -2, 7], [10, -4, 1360]));
        let mut i2c = Mock::new(&t);
        let mut imu = Bmi088::new(i2c.clone());
        for _ in 0..FROZEN_REPEATS {
            assert!(imu.read().is_ok());
        }
        assert_eq!(
            imu.read(),
            Err(SensorError::Frozen {
                device: "BMI088",
                repeats: FROZEN_REPEATS
            })
        );
        // One changed bit and it is live again.
        assert!(imu.read().is_ok());
        i2c.done();
    }

    /// The interrupt-driven sample over the modelled peripheral: the same
    /// sample as the blocking read; a part that stops answering is an
    /// error naming it; a sample still on the bus at the next data-ready
    /// is abandoned and the next one read.
    #[test]
    fn the_interrupt_driven_sample_reads_both_halves_and_bounds_itself() {
        use crate::i2c_model::{part, Bus};
        let mut gyro = part(0x69, 0x0F);
        let mut acc = part(0x18, 0x1E);
        gyro.regs[0x02..0x08].copy_from_slice(&[100, 0, 0, 0, 0, 0]);
        acc.regs[0x12..0x18].copy_from_slice(&[0, 0, 0, 0, 0x55, 0x05]);
        let bus = Bus::new(vec![gyro, acc]);
        let _m = crate::i2c::I2cMaster::new(&bus);
        let mut rd = SampleReader::new();
        let sample = |rd: &mut SampleReader| {
            rd.data_ready(&&bus).unwrap();
            for _ in 0..100 {
                let out = if bus.error_pending() {
                    rd.on_error(&&bus)
                } else {
                    rd.on_event(&&bus)
                };
                if let Some(r) = out {
                    return r;
                }
            }
            panic!("no sample")
        };
        let want = sample_from_raw(&[100, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0x55, 0x05]);
        assert_eq!(sample(&mut rd), Ok(want));
        // The accelerometer gone: the gyroscope's half read, then a NACK.
        bus.0.borrow_mut().parts.truncate(1);
        assert_eq!(
            sample(&mut rd),
            Err(SensorError::Bus {
                device: "BMI088 accelerometer",
                kind: ErrorKind::NoAcknowledge(NoAcknowledgeSource::Address)
            })
        );
        // A data-ready while a sample is on the bus: that one is missing.
        rd.data_ready(&&bus).unwrap();
        rd.on_event(&&bus);
        assert!(rd.busy());
        assert!(matches!(rd.data_ready(&&bus), Err(SensorError::Timeout { .. })));
        assert!(rd.busy(), "the next sample started");
    }
}
