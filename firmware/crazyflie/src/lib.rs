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
//! - [`motors`]: the brushed motors on TIM2 and TIM4 (8-bit PWM at 328 kHz),
//!   the Crazyflie 2.1's thrust curve and battery compensation;
//! - [`leds`]: what the five LEDs show for each state;
//! - [`supervisor`]: the "can fly" checks, tumble detection and the sensor
//!   watchdog (a silent sensor → failsafe descent);
//! - [`watchdog`]: the independent watchdog's plan and its feeding rule (fed
//!   only when the IMU task and the controller both made progress).
//!
//! Every wait is bounded, every fallible step returns a [`SensorError`] (or
//! the module's own error) that names what was wrong, and nothing allocates.
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]

pub mod bmi088;
pub mod bmp388;
mod error;
pub mod leds;
pub mod motors;
pub mod pins;
pub mod supervisor;
pub mod watchdog;

pub use error::SensorError;
