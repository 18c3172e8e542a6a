//! # hal-shim — what the control loop needs from the hardware, and nothing more
//!
//! Three traits: a byte link to the ground/plant, a cycle clock for timing,
//! and an actuator output. The firmware's control loop is written against
//! these; the STM32F405 implementations and the host implementations (for
//! the SIL) live behind them. `#![no_std]` unless the `std` feature is on.
#![cfg_attr(not(feature = "std"), no_std)]
#![deny(missing_docs)]

/// A non-blocking byte stream (a UART on the MCU, a socket or pipe on the host).
///
/// An implementation over two fixed buffers (what a test double or a DMA
/// ring looks like; `no_std`, nothing allocated):
///
/// ```
/// use hal_shim::ByteLink;
///
/// /// Reads from `rx`, writes into `tx`; fails when `tx` is full.
/// struct Buffers<'a> { rx: &'a [u8], tx: heapless::Vec<u8, 16> }
///
/// #[derive(Debug)]
/// struct Full;
///
/// impl ByteLink for Buffers<'_> {
///     type Error = Full;
///     fn read(&mut self, buf: &mut [u8]) -> Result<usize, Full> {
///         let n = buf.len().min(self.rx.len());
///         buf[..n].copy_from_slice(&self.rx[..n]);
///         self.rx = &self.rx[n..];
///         Ok(n)
///     }
///     fn write_all(&mut self, bytes: &[u8]) -> Result<(), Full> {
///         self.tx.extend_from_slice(bytes).map_err(|_| Full)
///     }
/// }
///
/// let mut link = Buffers { rx: b"ab", tx: heapless::Vec::new() };
/// let mut buf = [0u8; 8];
/// assert_eq!(link.read(&mut buf).unwrap(), 2);
/// assert_eq!(link.read(&mut buf).unwrap(), 0); // nothing waiting: no blocking
/// assert!(link.write_all(&[1; 16]).is_ok());
/// assert!(link.write_all(&[1]).is_err()); // full: an error, not a hang
/// ```
pub trait ByteLink {
    /// Error a transfer can report (overrun, framing, closed link).
    type Error: core::fmt::Debug;
    /// Reads whatever bytes are available into `buf` without blocking;
    /// returns how many were read (0 when none are waiting).
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error>;
    /// Queues all of `bytes` for sending.
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), Self::Error>;
}

/// A free-running counter of CPU cycles (DWT CYCCNT on silicon; SysTick
/// instruction counts under QEMU `-icount`).
pub trait CycleClock {
    /// Current count; wraps at `u32::MAX`.
    fn now(&self) -> u32;
    /// Counts per second of the source.
    fn hz(&self) -> u32;
    /// Cycles elapsed from `start` to now, wrap-safe.
    fn since(&self, start: u32) -> u32 {
        self.now().wrapping_sub(start)
    }
}

/// Where the inputs `U` end up: ESC outputs on the vehicle, the plant in the SIL.
pub trait ActuatorOutput {
    /// Applies `u = [U1 N, U2 N, U3 N, U4 N·m]`. Values are already inside the
    /// input box; implementations map them to rotor commands.
    fn apply(&mut self, u: [f32; 4]);
    /// Stops all rotors (disarm).
    fn disarm(&mut self);
}

/// STM32F405 implementations (built for the MCU target only).
#[cfg(feature = "stm32f405")]
pub mod stm32f405;

/// Host implementations for the SIL and tests.
#[cfg(feature = "std")]
pub mod host {
    use super::{ActuatorOutput, ByteLink, CycleClock};
    use std::collections::VecDeque;

    /// An in-memory byte link: what is written to one end is read at the other.
    #[derive(Debug, Default)]
    pub struct LoopbackLink {
        /// Bytes waiting to be read.
        pub rx: VecDeque<u8>,
        /// Bytes written so far.
        pub tx: Vec<u8>,
    }

    impl ByteLink for LoopbackLink {
        type Error = core::convert::Infallible;
        fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
            let n = buf.len().min(self.rx.len());
            for (dst, src) in buf.iter_mut().zip(self.rx.drain(..n)) {
                *dst = src;
            }
            Ok(n)
        }
        fn write_all(&mut self, bytes: &[u8]) -> Result<(), Self::Error> {
            self.tx.extend_from_slice(bytes);
            Ok(())
        }
    }

    /// A cycle clock driven by the host's monotonic clock, in nanoseconds.
    #[derive(Debug)]
    pub struct MonotonicClock {
        start: std::time::Instant,
    }

    impl Default for MonotonicClock {
        fn default() -> Self {
            Self {
                start: std::time::Instant::now(),
            }
        }
    }

    impl CycleClock for MonotonicClock {
        fn now(&self) -> u32 {
            self.start.elapsed().as_nanos() as u32
        }
        fn hz(&self) -> u32 {
            1_000_000_000
        }
    }

    /// Records the last applied input, for the in-process SIL.
    #[derive(Debug, Default, Clone, Copy)]
    pub struct RecordingActuators {
        /// Last input applied (zeros after disarm).
        pub last: [f32; 4],
    }

    impl ActuatorOutput for RecordingActuators {
        fn apply(&mut self, u: [f32; 4]) {
            self.last = u;
        }
        fn disarm(&mut self) {
            self.last = [0.0; 4];
        }
    }
}
