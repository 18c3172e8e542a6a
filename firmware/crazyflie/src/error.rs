//! What a sensor driver reports when it cannot give a sample.

use embedded_hal::i2c::ErrorKind;

/// Why a sensor driver gave no sample (or refused to start). Every variant
/// names the device; none is recoverable by the driver itself: the
/// supervisor counts them and decides (retry at the next tick, or failsafe).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensorError {
    /// The I2C transfer failed (NACK, arbitration loss, a bus the HAL gave
    /// up on after its bounded wait).
    Bus {
        /// The device addressed.
        device: &'static str,
        /// What the bus reported.
        kind: ErrorKind,
    },
    /// The device answered with another chip id: not the part expected, or
    /// a bus that returns garbage.
    ChipId {
        /// The device addressed.
        device: &'static str,
        /// The datasheet's chip id.
        expected: u8,
        /// What it read.
        found: u8,
    },
    /// A configuration register did not read back what was written.
    Config {
        /// The device.
        device: &'static str,
        /// The register address.
        register: u8,
        /// What was written.
        wrote: u8,
        /// What was read back.
        read: u8,
    },
    /// The device reported an error flag (its ERR register).
    DeviceError {
        /// The device.
        device: &'static str,
        /// The ERR register's value.
        flags: u8,
    },
    /// The same raw sample, bit for bit, this many reads in a row: the
    /// sensor's noise alone makes that impossible for a live one.
    Frozen {
        /// The device.
        device: &'static str,
        /// Identical reads in a row.
        repeats: u16,
    },
    /// A compensated value outside what the part can measure.
    Implausible {
        /// The device.
        device: &'static str,
        /// The quantity (with its unit).
        quantity: &'static str,
    },
    /// A bounded wait for the device's status ran out.
    Timeout {
        /// The device.
        device: &'static str,
        /// Polls made before giving up.
        polls: u16,
    },
}

impl SensorError {
    /// A bus error from any embedded-hal I2C error.
    pub(crate) fn bus<E: embedded_hal::i2c::Error>(device: &'static str, e: E) -> Self {
        SensorError::Bus { device, kind: e.kind() }
    }

    /// An interrupt-driven burst to `device` that failed: its bounded wait
    /// ran out (a timeout), or the bus reported the error.
    pub(crate) fn of_burst(device: &'static str, e: crate::i2c::I2cError) -> Self {
        match e {
            crate::i2c::I2cError::Timeout(_) => SensorError::Timeout { device, polls: 0 },
            e => SensorError::bus(device, e),
        }
    }

    /// The device the error is about.
    pub fn device(&self) -> &'static str {
        match *self {
            SensorError::Bus { device, .. }
            | SensorError::ChipId { device, .. }
            | SensorError::Config { device, .. }
            | SensorError::DeviceError { device, .. }
            | SensorError::Frozen { device, .. }
            | SensorError::Implausible { device, .. }
            | SensorError::Timeout { device, .. } => device,
        }
    }
}

impl core::fmt::Display for SensorError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            SensorError::Bus { device, kind } => write!(f, "{device}: I2C transfer failed ({kind})"),
            SensorError::ChipId {
                device,
                expected,
                found,
            } => write!(f, "{device}: chip id {found:#04x}, expected {expected:#04x}"),
            SensorError::Config {
                device,
                register,
                wrote,
                read,
            } => write!(
                f,
                "{device}: register {register:#04x} reads {read:#04x} after writing {wrote:#04x}"
            ),
            SensorError::DeviceError { device, flags } => write!(f, "{device}: error flags {flags:#04x}"),
            SensorError::Frozen { device, repeats } => {
                write!(f, "{device}: the same raw sample {repeats} times in a row (frozen)")
            }
            SensorError::Implausible { device, quantity } => write!(f, "{device}: implausible {quantity}"),
            SensorError::Timeout { device, polls } => write!(f, "{device}: not ready after {polls} polls"),
        }
    }
}

/// Counts identical raw samples in a row: a live sensor's noise changes at
/// least one bit of every sample, so `limit` repeats mean the part (or the
/// bus) stopped delivering new data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct FreezeWatch<const N: usize> {
    last: [u8; N],
    repeats: u16,
    limit: u16,
}

impl<const N: usize> FreezeWatch<N> {
    pub(crate) const fn new(limit: u16) -> Self {
        Self {
            last: [0; N],
            repeats: 0,
            limit,
        }
    }

    /// Records a raw sample; `Err` with the count once it reaches the limit.
    pub(crate) fn check(&mut self, device: &'static str, raw: &[u8; N]) -> Result<(), SensorError> {
        if *raw == self.last {
            self.repeats = self.repeats.saturating_add(1);
        } else {
            self.repeats = 0;
            self.last = *raw;
        }
        if self.repeats >= self.limit {
            Err(SensorError::Frozen {
                device,
                repeats: self.repeats,
            })
        } else {
            Ok(())
        }
    }
}
