//! A sensor's health, as PX4's data validator judges it: a source that
//! goes silent, repeats itself (a stuck value: real sensors have noise,
//! so the same reading many times in a row is a frozen driver or bus), or
//! that keeps disagreeing with the estimate ([`plausible`]).
//!
//! One [`Watch`] per source (a position fix, the barometer, the
//! magnetometer). The front end that takes the source's data hands each
//! reading's fingerprint to [`Watch::sample`] (a hash of its values,
//! [`fingerprint`]), whether it agrees with the estimate to
//! [`Watch::judged`] ([`plausible`]),
//! and calls [`Watch::tick`] every step. In flight ([`Watch::fly`]), a
//! source found stuck or refused is not believed again
//! ([`Watch::usable`] stays `false` until [`Watch::restart`], on the
//! ground): a sensor that has lied once is not the one to land by. On the
//! ground the same faults are a preflight check's: they hold until the
//! source reads well again (a new value, a fused reading). One that went
//! silent is taken again when it comes back.

/// Readings in a row with the same values (the same [`fingerprint`]):
/// stuck. PX4's data
/// validator waits for 100 of its 200 Hz–1 kHz sensors' samples; the
/// sources watched here come at 20–100 Hz.
pub const STUCK_READINGS: u16 = 20;

/// Readings in a row that are implausible ([`plausible`]): the source is
/// wrong. Below the estimator's reset to a position fix after 20 refusals
/// ([`fc_core::estimate::EskfConfig::reset_after_rejections`]), so that a
/// fix that is wrong by metres is found before it is believed.
pub const REFUSED_READINGS: u16 = 10;

/// Whether a reading whose innovation (its distance from the estimate, in
/// the reading's unit) is `innovation` agrees with an estimate of 1σ
/// `sigma`: within the estimator's gate (5σ) or within `floor`. The floor
/// keeps the estimator's own brief disagreements out (a lift-off, where
/// the filter refuses a few centimetres for tens of fixes in a row and
/// then resets to them); a reading beyond both is a wrong sensor.
pub fn plausible(innovation: f32, sigma: f32, floor: f32) -> bool {
    let gate = fc_core::estimate::EskfConfig::BMI088.gate_sigma * sigma;
    innovation.abs() <= gate.max(floor)
}

/// No reading for this long: silent, µs.
pub const SILENT_US: u64 = 500_000;

const _: () = assert!(REFUSED_READINGS < fc_core::estimate::EskfConfig::BMI088.reset_after_rejections);
// The silent fault's text says 0.5 s.
const _: () = assert!(SILENT_US == 500_000);

/// What is wrong with a source.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Fault {
    /// No reading for [`SILENT_US`].
    Silent,
    /// [`STUCK_READINGS`] readings in a row the same.
    Stuck,
    /// [`REFUSED_READINGS`] readings in a row implausible ([`plausible`]).
    Refused,
}

impl core::fmt::Display for Fault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            // SILENT_US in seconds, as the ground station reads it.
            Fault::Silent => f.write_str("silent 0.5 s"),
            Fault::Stuck => write!(f, "stuck ({STUCK_READINGS} the same)"),
            Fault::Refused => write!(f, "wrong ({REFUSED_READINGS} in a row)"),
        }
    }
}

/// A change of a source's health, for the vehicle to say.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Change {
    /// The source is not used from now on (a silent one until it is back).
    Lost(Fault),
    /// A silent source reads again and is used.
    Back,
}

/// One source's health (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Watch {
    last_us: Option<u64>,
    last_print: Option<u32>,
    same: u16,
    refused: u16,
    fault: Option<Fault>,
    flying: bool,
}

impl Watch {
    /// A source not heard yet.
    pub const fn new() -> Self {
        Self {
            last_us: None,
            last_print: None,
            same: 0,
            refused: 0,
            fault: None,
            flying: false,
        }
    }

    /// Armed (`true`: a condemned source stays so) or on the ground.
    pub fn fly(&mut self, flying: bool) {
        self.flying = flying;
    }

    /// A reading at `t_us` whose values hash to `print`; the change it
    /// makes, if any. Use the reading only if [`Watch::usable`] after it.
    /// Only `airborne` readings count towards stuck: at rest on the ground
    /// a simulator's truth (and a quiet barometer's reading) may well be the
    /// same, bit for bit, for seconds.
    pub fn sample(&mut self, t_us: u64, print: u32, airborne: bool) -> Option<Change> {
        self.last_us = Some(t_us);
        self.same = if self.last_print == Some(print) && airborne {
            self.same.saturating_add(1)
        } else {
            0
        };
        self.last_print = Some(print);
        match self.fault {
            Some(Fault::Silent) => {
                self.fault = None;
                Some(Change::Back)
            }
            Some(Fault::Stuck) if !self.flying && self.same == 0 => {
                self.fault = None;
                Some(Change::Back)
            }
            None if self.same + 1 >= STUCK_READINGS => {
                self.fault = Some(Fault::Stuck);
                Some(Change::Lost(Fault::Stuck))
            }
            _ => None,
        }
    }

    /// Whether a reading of this source agrees with the estimate
    /// ([`plausible`]); the change it makes, if any.
    pub fn judged(&mut self, fused: bool) -> Option<Change> {
        self.refused = if fused { 0 } else { self.refused.saturating_add(1) };
        if fused && !self.flying && self.fault == Some(Fault::Refused) {
            self.fault = None;
            return Some(Change::Back);
        }
        if self.fault.is_none() && self.refused >= REFUSED_READINGS {
            self.fault = Some(Fault::Refused);
            return Some(Change::Lost(Fault::Refused));
        }
        None
    }

    /// A step at `t_us`: a source heard before and not since [`SILENT_US`]
    /// is silent.
    pub fn tick(&mut self, t_us: u64) -> Option<Change> {
        let silent = self.last_us.is_some_and(|t| t_us.saturating_sub(t) > SILENT_US);
        if silent && self.fault.is_none() {
            self.fault = Some(Fault::Silent);
            return Some(Change::Lost(Fault::Silent));
        }
        None
    }

    /// Whether the source's readings are used.
    pub fn usable(&self) -> bool {
        self.fault.is_none()
    }

    /// What is wrong, if anything.
    pub fn fault(&self) -> Option<Fault> {
        self.fault
    }

    /// Heard at least once since the last [`Watch::restart`].
    pub fn heard(&self) -> bool {
        self.last_us.is_some()
    }

    /// A new flight (on the ground, or a new time line): every fault forgotten.
    pub fn restart(&mut self) {
        *self = Self::new();
    }

    /// Whether a reading is to be handed to the estimator: usable, or on
    /// the ground (where the estimator's verdicts on it may clear it).
    pub fn feeds(&self) -> bool {
        self.usable() || !self.flying
    }
}

/// A reading's fingerprint: FNV-1a over `words` (the readings' bits).
pub fn fingerprint(words: &[u32]) -> u32 {
    words.iter().fold(0x811c_9dc5, |h, w| {
        w.to_le_bytes()
            .iter()
            .fold(h, |h, b| (h ^ u32::from(*b)).wrapping_mul(0x0100_0193))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_noisy_source_stays_good_and_a_frozen_one_is_stuck_after_twenty() {
        let mut w = Watch::new();
        w.fly(true);
        // At rest, the same reading for ever is no fault.
        for k in 0..1000u64 {
            assert_eq!(w.sample(k * 10_000, 42, false), None);
        }
        assert!(w.usable());
        for k in 0..1000u32 {
            assert_eq!(w.sample(u64::from(k) * 10_000, fingerprint(&[k, 7]), true), None);
            assert_eq!(w.tick(u64::from(k) * 10_000 + 1), None);
        }
        assert!(w.usable());
        // Frozen: the first reading repeated is the second of its run.
        let t0 = 10_000_000;
        for k in 0..(STUCK_READINGS - 1) {
            assert_eq!(w.sample(t0 + u64::from(k) * 10_000, 42, true), None, "reading {k}");
        }
        assert_eq!(w.sample(t0 + 1_000_000, 42, true), Some(Change::Lost(Fault::Stuck)));
        assert!(!w.usable());
        // A stuck source that moves again is not believed in this flight.
        assert_eq!(w.sample(t0 + 1_010_000, 43, true), None);
        assert_eq!(w.fault(), Some(Fault::Stuck));
        w.restart();
        assert!(w.usable() && !w.heard());
        // On the ground: stuck until it moves again.
        for k in 0..STUCK_READINGS {
            let _ = w.sample(u64::from(k) * 10_000, 42, true);
        }
        assert_eq!(w.fault(), Some(Fault::Stuck));
        assert!(w.feeds());
        assert_eq!(w.sample(1_000_000, 43, true), Some(Change::Back));
    }

    #[test]
    fn ten_refusals_in_a_row_condemn_it_and_one_fused_between_does_not() {
        let mut w = Watch::new();
        w.fly(true);
        for _ in 0..100 {
            for _ in 0..(REFUSED_READINGS - 1) {
                assert_eq!(w.judged(false), None);
            }
            assert_eq!(w.judged(true), None);
        }
        assert!(w.usable());
        for _ in 0..(REFUSED_READINGS - 1) {
            assert_eq!(w.judged(false), None);
        }
        assert_eq!(w.judged(false), Some(Change::Lost(Fault::Refused)));
        assert_eq!(w.judged(true), None);
        assert!(!w.usable() && !w.feeds());
        // On the ground, a reading fused clears it.
        w.fly(false);
        assert!(w.feeds());
        assert_eq!(w.judged(true), Some(Change::Back));
        assert!(w.usable());
    }

    #[test]
    fn a_silent_source_is_lost_after_half_a_second_and_back_when_it_reads() {
        let mut w = Watch::new();
        // Never heard: not silent (a vehicle without the sensor).
        assert_eq!(w.tick(10_000_000), None);
        assert_eq!(w.sample(0, 1, true), None);
        assert_eq!(w.tick(SILENT_US), None);
        assert_eq!(w.tick(SILENT_US + 1), Some(Change::Lost(Fault::Silent)));
        assert_eq!(w.tick(SILENT_US + 2), None);
        assert!(!w.usable());
        assert_eq!(w.sample(SILENT_US + 3, 2, true), Some(Change::Back));
        assert!(w.usable());
    }

    #[test]
    fn plausible_is_within_the_gate_or_the_floor() {
        // 5σ of 1 cm, or the floor of 0.5 m.
        assert!(plausible(0.49, 0.01, 0.5) && !plausible(0.51, 0.01, 0.5));
        assert!(plausible(-0.49, 0.01, 0.5) && !plausible(-0.51, 0.01, 0.5));
        // Dead reckoning (1σ 0.3 m): a fix 1.4 m off still agrees.
        assert!(plausible(1.4, 0.3, 0.5) && !plausible(1.6, 0.3, 0.5));
        assert!(!plausible(f32::NAN, 0.01, 0.5));
    }

    #[test]
    fn the_fingerprint_tells_one_bit_apart() {
        let a = fingerprint(&[1.0f32.to_bits(), 2.0f32.to_bits()]);
        let b = fingerprint(&[1.0f32.to_bits(), f32::from_bits(2.0f32.to_bits() ^ 1).to_bits()]);
        assert_ne!(a, b);
        assert_eq!(a, fingerprint(&[1.0f32.to_bits(), 2.0f32.to_bits()]));
    }
}
