//! # fc-crazyflie — the Crazyflie 2.1 board
//!
//! What the flight controller needs to know and do on Bitcraze's Crazyflie
//! 2.1 (an STM32F405RG at 168 MHz from an 8 MHz crystal, the same clock tree
//! as `fc-stm32f405`), each part generic over embedded-hal 1.0 or over the
//! `stm32f4` PAC's register blocks so that all of it is tested on the host:
//!
//! - [`pins`]: every pin the image uses, from the official firmware's sources;
//! - [`bmi088`]: the IMU on I2C3 (accelerometer 0x18, gyroscope 0x69),
//!   configured as the official firmware configures it, in body FRD;
//! - [`bmp388`]: the barometer at 0x77 with Bosch's compensation;
//! - [`i2c`]: the STM32F4's I2C master (RM0090 §27), blocking with bounded
//!   waits for start-up, interrupt-driven for the 1 kHz sample;
//! - [`reads`]: what the sensor bus reads and when (the IMU at 1 kHz, the
//!   barometer after every 20th sample), on its interrupts, bounded by the
//!   IMU's period;
//! - [`sensor_bus`]: I2C3's pins and the gyroscope's data-ready line
//!   (PC14, EXTI14) on the chip;
//! - [`motors`]: the brushed motors on TIM2 and TIM4 (8-bit PWM at 328 kHz),
//!   the Crazyflie 2.1's thrust curve and battery compensation;
//! - [`leds`]: what the five LEDs show for each state;
//! - [`supervisor`]: the board's part of the vehicle's supervisor (whether
//!   its sensors started, named in the arming refusal; a failed read is a
//!   missing sample, which the vehicle holds for 10 ms, then descends);
//!
//! The independent watchdog's plan and its feeding rule (fed only when the
//! IMU task and the controller both made progress) are the chip's, shared
//! with the plain STM32F405's CRTP image: `fc_stm32f405::watchdog`.
//!
//! Every wait is bounded, every fallible step returns a [`SensorError`] (or
//! the module's own error) that names what was wrong, and nothing allocates.
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]

pub mod bmi088;
pub mod bmp388;
mod error;
pub mod i2c;
#[cfg(test)]
mod i2c_model;
pub mod leds;
pub mod motors;
pub mod pins;
pub mod reads;
pub mod sensor_bus;
pub mod supervisor;

pub use error::SensorError;

/// Where the IMU task gets its sample: the BMI088 on the board
/// ([`bmi088::Bmi088`]), or in QEMU (which models no I2C) the simulator's
/// sample that arrived over a USART. The IMU task is the same either way;
/// only this implementation is swapped.
pub trait ImuSource {
    /// The newest sample, body FRD, or why there is none.
    fn sample(&mut self) -> Result<bmi088::ImuSample, SensorError>;
}

impl<I: embedded_hal::i2c::I2c> ImuSource for bmi088::Bmi088<I> {
    fn sample(&mut self) -> Result<bmi088::ImuSample, SensorError> {
        self.read()
    }
}

/// Where the barometer task gets its sample (the BMP388, or a simulator's).
pub trait BaroSource {
    /// The newest compensated sample, or why there is none.
    fn sample(&mut self) -> Result<bmp388::BaroSample, SensorError>;
}

impl<I: embedded_hal::i2c::I2c> BaroSource for bmp388::Bmp388<I> {
    fn sample(&mut self) -> Result<bmp388::BaroSample, SensorError> {
        bmp388::Bmp388::sample(self)
    }
}
