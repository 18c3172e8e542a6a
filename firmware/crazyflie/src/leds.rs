//! The five LEDs and what they show. Blue left (PD2) is active high; the
//! red and green ones (PC0–PC3) are active low ([`crate::pins`]).
//!
//! | state | blue L | green L, R | red L, R |
//! |---|---|---|---|
//! | booting | on | off | off |
//! | aligning (estimator not yet aligned) | on | off | blink 2 Hz |
//! | ready (can fly, disarmed) | on | blink 1 Hz | off |
//! | armed | on | on | off |
//! | failsafe descent | on | off | blink 5 Hz |
//! | fault (tumbled, sensor lost on the ground, hard fault) | off | off | on |

use embedded_hal::digital::OutputPin;

/// What the board is doing, for the LEDs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Indication {
    /// Drivers and estimator starting.
    Booting,
    /// Waiting for the estimator to align (vehicle must be still).
    Aligning,
    /// Every "can fly" check passed; disarmed.
    Ready,
    /// Motors armed.
    Armed,
    /// Failsafe descent in progress.
    Failsafe,
    /// Motors off after a fault.
    Fault,
}

/// Which LEDs are lit: blue left, green left, green right, red left, red right.
pub type Lit = [bool; 5];

/// The LEDs lit for `ind` at time `t_ms` (blinks are square waves of that clock).
pub fn pattern(ind: Indication, t_ms: u32) -> Lit {
    let blink = |hz: u32| (u64::from(t_ms) * u64::from(hz) * 2 / 1000).is_multiple_of(2);
    match ind {
        Indication::Booting => [true, false, false, false, false],
        Indication::Aligning => {
            let r = blink(2);
            [true, false, false, r, r]
        }
        Indication::Ready => {
            let g = blink(1);
            [true, g, g, false, false]
        }
        Indication::Armed => [true, true, true, false, false],
        Indication::Failsafe => {
            let r = blink(5);
            [true, false, false, r, r]
        }
        Indication::Fault => [false, false, false, true, true],
    }
}

/// The five LED pins, in [`Lit`]'s order, and their polarity.
pub struct Leds<P> {
    pins: [P; 5],
}

/// Which LEDs light when their pin is high (only the blue one).
pub const ACTIVE_HIGH: Lit = [true, false, false, false, false];

impl<P: OutputPin> Leds<P> {
    /// The pins: blue left (PD2), green left (PC1), green right (PC2), red
    /// left (PC0), red right (PC3).
    pub fn new(pins: [P; 5]) -> Self {
        Self { pins }
    }

    /// Drives every pin for `lit`; the first pin error is returned after
    /// all five were tried.
    pub fn show(&mut self, lit: Lit) -> Result<(), P::Error> {
        let mut first = Ok(());
        for (i, pin) in self.pins.iter_mut().enumerate() {
            let r = if lit[i] == ACTIVE_HIGH[i] {
                pin.set_high()
            } else {
                pin.set_low()
            };
            if first.is_ok() {
                first = r;
            }
        }
        first
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_hal_mock::eh1::digital::{Mock, State, Transaction as T};

    #[test]
    fn lit_red_and_green_leds_pull_their_pins_low() {
        // Armed: blue high (lit), greens low (lit), reds high (dark).
        let expect = [State::High, State::Low, State::Low, State::High, State::High];
        let mut pins: Vec<Mock> = expect.iter().map(|s| Mock::new(&[T::set(*s)])).collect();
        let mut leds = Leds::new(core::array::from_fn(|i| pins[i].clone()));
        leds.show(pattern(Indication::Armed, 0)).unwrap();
        pins.iter_mut().for_each(Mock::done);
        // Fault: blue low (dark), reds low (lit), greens high (dark).
        let expect = [State::Low, State::High, State::High, State::Low, State::Low];
        let mut pins: Vec<Mock> = expect.iter().map(|s| Mock::new(&[T::set(*s)])).collect();
        let mut leds = Leds::new(core::array::from_fn(|i| pins[i].clone()));
        leds.show(pattern(Indication::Fault, 0)).unwrap();
        pins.iter_mut().for_each(Mock::done);
    }

    #[test]
    fn blinks_have_the_stated_rates() {
        let toggles = |ind, led: usize| {
            (1..2000)
                .filter(|&t| pattern(ind, t)[led] != pattern(ind, t - 1)[led])
                .count()
        };
        // Over 2 s: a 2 Hz blink toggles 8 times, 1 Hz 4 times, 5 Hz 20 times.
        assert_eq!(toggles(Indication::Aligning, 3), 7);
        assert_eq!(toggles(Indication::Ready, 1), 3);
        assert_eq!(toggles(Indication::Failsafe, 4), 19);
        assert_eq!(toggles(Indication::Armed, 1), 0);
    }
}
