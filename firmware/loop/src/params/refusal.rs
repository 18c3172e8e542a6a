//! Why a write was refused, and numbers said without `f32`'s formatting.

use fc_core::control::{ControlError, SpecError};
use fc_core::model::airframe::MixerError;

/// Why a parameter write was refused (each short enough for a 50-character
/// `STATUSTEXT` after the parameter's name).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Refusal {
    /// No parameter has this name (or index).
    Unknown,
    /// The value is outside `[lo, hi]` (or not finite).
    Range {
        /// Smallest accepted.
        lo: f32,
        /// Largest accepted.
        hi: f32,
    },
    /// An integer-valued parameter was given a fraction.
    NotInteger,
    /// The controller id names no controller of this firmware.
    Controller(SpecError),
    /// The motors cannot be mixed with these settings.
    Mixer(MixerError),
    /// The controller could not be designed for the new settings.
    Design(ControlError),
    /// The change re-designs the controller: only while disarmed.
    Armed,
    /// A re-design is under way (in the controller's task): write again
    /// once it is answered.
    Busy,
}

impl Refusal {
    /// Its code in our protocol's `Param` answer (0 there: not refused).
    pub fn code(&self) -> u8 {
        match self {
            Refusal::Unknown => 1,
            Refusal::Range { .. } => 2,
            Refusal::NotInteger => 3,
            Refusal::Controller(_) => 4,
            Refusal::Mixer(_) => 5,
            Refusal::Design(_) => 6,
            Refusal::Armed => 7,
            Refusal::Busy => 8,
        }
    }
}

impl core::fmt::Display for Refusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Refusal::Unknown => f.write_str("no such parameter"),
            Refusal::Range { lo, hi } => write!(f, "out of [{}, {}]", Num(*lo), Num(*hi)),
            Refusal::NotInteger => f.write_str("must be a whole number"),
            Refusal::Controller(_) => f.write_str("no controller has this id"),
            Refusal::Mixer(MixerError::Singular) => f.write_str("rotor layout is singular"),
            Refusal::Mixer(MixerError::PwmRange) => f.write_str("PWM max must exceed min"),
            Refusal::Mixer(MixerError::Parameter(_)) => f.write_str("mixer needs a positive value"),
            Refusal::Design(_) => f.write_str("controller design failed"),
            Refusal::Armed => f.write_str("disarm first"),
            Refusal::Busy => f.write_str("a re-design is under way"),
        }
    }
}

/// A number in at most six significant digits (`0.01`, `100`, `-1`,
/// `1.5e-7`), written with integer formatting only: `f32`'s own `Display`
/// links ≈ 20 KiB of float-printing code into the image for a few
/// `STATUSTEXT`s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f32);

impl core::fmt::Display for Num {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let x = self.0;
        if x.is_nan() {
            return f.write_str("NaN");
        }
        if x < 0.0 {
            f.write_str("-")?;
        }
        let a = libm::fabsf(x);
        if a.is_infinite() {
            return f.write_str("inf");
        }
        if a == 0.0 {
            return f.write_str("0");
        }
        // a = m · 10^e with m in [1, 10); plain notation for e in [-3, 6).
        let mut e = libm::floorf(libm::log10f(a)) as i32;
        let scaled = |e: i32| f64::from(a) / libm::pow(10.0, f64::from(e));
        // Six significant digits: an integer in [100 000, 1 000 000).
        let mut n = libm::round(scaled(e) * 1e5) as u64;
        if n >= 1_000_000 {
            e += 1;
            n = libm::round(scaled(e) * 1e5) as u64;
        }
        let (mut digits, mut len) = ([0u8; 6], 6);
        for d in digits.iter_mut().rev() {
            *d = b'0' + (n % 10) as u8;
            n /= 10;
        }
        while len > 1 && digits[len - 1] == b'0' {
            len -= 1;
        }
        let d = |i: usize| if i < len { digits[i] as char } else { '0' };
        let plain = (-3..6).contains(&e);
        if !plain {
            write!(f, "{}", d(0))?;
            if len > 1 {
                f.write_str(".")?;
                (1..len).try_for_each(|i| write!(f, "{}", d(i)))?;
            }
            return write!(f, "e{e}");
        }
        if e < 0 {
            f.write_str("0.")?;
            (0..(-e - 1)).try_for_each(|_| f.write_str("0"))?;
            return (0..len).try_for_each(|i| write!(f, "{}", d(i)));
        }
        let int_digits = e as usize + 1;
        (0..int_digits).try_for_each(|i| write!(f, "{}", d(i)))?;
        if len > int_digits {
            f.write_str(".")?;
            (int_digits..len).try_for_each(|i| write!(f, "{}", d(i)))?;
        }
        Ok(())
    }
}
