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
/// `STATUSTEXT`s. Its only f64 work is a few products with exact powers of
/// ten (the M4 has no f64 unit: libm's `pow` took thousands of
/// instructions here, under the vehicle's lock on the CRTP images).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f32);

/// 10⁰ to 10²², every one exact in f64.
const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16, 1e17, 1e18, 1e19, 1e20,
    1e21, 1e22,
];

/// `a · 10^k` rounded to an integer, for `a` a positive finite f32 and `k`
/// in [−34, 51] (at most three products or quotients by exact powers).
fn scaled(a: f32, k: i32) -> u64 {
    let mut v = f64::from(a);
    let mut k = k;
    while k > 22 {
        v *= POW10[22];
        k -= 22;
    }
    while k < -22 {
        v /= POW10[22];
        k += 22;
    }
    let p = POW10[k.unsigned_abs() as usize];
    let v = if k >= 0 { v * p } else { v / p };
    libm::round(v) as u64
}

impl Num {
    /// The text of the number (at most 13 characters: `-1.23456e-45`).
    /// A push past the capacity is dropped (none is: 16 holds them all).
    fn text(&self) -> heapless::String<16> {
        let mut t = heapless::String::<16>::new();
        let x = self.0;
        if x.is_nan() {
            let _ = t.push_str("NaN");
            return t;
        }
        if x < 0.0 {
            let _ = t.push('-');
        }
        let a = libm::fabsf(x);
        if a.is_infinite() {
            let _ = t.push_str("inf");
            return t;
        }
        if a == 0.0 {
            let _ = t.push('0');
            return t;
        }
        // a = m · 10^e with m in [1, 10); plain notation for e in [-3, 6).
        // f32's range puts e in [-45, 38].
        let mut e = libm::floorf(libm::log10f(a)) as i32;
        // Six significant digits: an integer in [100 000, 1 000 000).
        let mut n = scaled(a, 5 - e);
        if n >= 1_000_000 {
            e += 1;
            n = scaled(a, 5 - e);
        } else if n < 100_000 {
            e -= 1;
            n = scaled(a, 5 - e);
        }
        // Below 10⁷: the M4 divides a u32 itself, a u64 by a library call.
        let mut n = n as u32;
        let (mut digits, mut len) = ([0u8; 6], 6);
        for d in digits.iter_mut().rev() {
            *d = b'0' + (n % 10) as u8;
            n /= 10;
        }
        while len > 1 && digits[len - 1] == b'0' {
            len -= 1;
        }
        let d = |i: usize| if i < len { char::from(digits[i]) } else { '0' };
        if !(-3..6).contains(&e) {
            let _ = t.push(d(0));
            if len > 1 {
                let _ = t.push('.');
                (1..len).for_each(|i| {
                    let _ = t.push(d(i));
                });
            }
            let _ = t.push('e');
            if e < 0 {
                let _ = t.push('-');
            }
            let m = e.unsigned_abs();
            if m >= 10 {
                let _ = t.push(char::from(b'0' + (m / 10) as u8));
            }
            let _ = t.push(char::from(b'0' + (m % 10) as u8));
            return t;
        }
        if e < 0 {
            let _ = t.push_str("0.");
            (0..(-e - 1)).for_each(|_| {
                let _ = t.push('0');
            });
            (0..len).for_each(|i| {
                let _ = t.push(d(i));
            });
            return t;
        }
        let int_digits = e as usize + 1;
        (0..int_digits).for_each(|i| {
            let _ = t.push(d(i));
        });
        if len > int_digits {
            let _ = t.push('.');
            (int_digits..len).for_each(|i| {
                let _ = t.push(d(i));
            });
        }
        t
    }
}

impl core::fmt::Display for Num {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(&self.text())
    }
}
