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

use embedded_hal::digital::{ErrorType, OutputPin};
use stm32f4::stm32f405::{gpioi, rcc};

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

/// One LED's pin on GPIOC or GPIOD (the F405's GPIOC–GPIOI share one
/// register layout), driven through BSRR: a set or a reset of that bit
/// alone, so no read-modify-write races another pin's.
pub struct LedPin {
    port: &'static gpioi::RegisterBlock,
    pin: u8,
}

impl ErrorType for LedPin {
    type Error = core::convert::Infallible;
}

impl OutputPin for LedPin {
    fn set_high(&mut self) -> Result<(), Self::Error> {
        // SAFETY: BSRR takes any value; bit `pin` (< 16) sets that pin.
        self.port.bsrr().write(|w| unsafe { w.bits(1 << self.pin) });
        Ok(())
    }

    fn set_low(&mut self) -> Result<(), Self::Error> {
        // SAFETY: bit `pin + 16` resets that pin.
        self.port.bsrr().write(|w| unsafe { w.bits(1 << (self.pin + 16)) });
        Ok(())
    }
}

/// The GPIOC and GPIOD clocks on, the five LEDs dark (driven to their
/// unlit level first, then made push-pull outputs), and the five pins in
/// [`Lit`]'s order: PD2, PC1, PC2, PC0, PC3.
pub fn apply_to(
    rcc: &rcc::RegisterBlock,
    gpioc: &'static gpioi::RegisterBlock,
    gpiod: &'static gpioi::RegisterBlock,
) -> Leds<LedPin> {
    rcc.ahb1enr().modify(|_, w| w.gpiocen().enabled().gpioden().enabled());
    let mut leds = Leds::new([
        LedPin { port: gpiod, pin: 2 },
        LedPin { port: gpioc, pin: 1 },
        LedPin { port: gpioc, pin: 2 },
        LedPin { port: gpioc, pin: 0 },
        LedPin { port: gpioc, pin: 3 },
    ]);
    let _ = leds.show([false; 5]);
    gpioc.moder().modify(|_, w| {
        w.moder(0)
            .output()
            .moder(1)
            .output()
            .moder(2)
            .output()
            .moder(3)
            .output()
    });
    gpiod.moder().modify(|_, w| w.moder(2).output());
    leds
}

/// On the chip: [`apply_to`] on the real RCC, GPIOC and GPIOD.
///
/// # Safety
/// The caller is the only code that touches those pins (the image's start-up, once).
#[cfg(target_os = "none")]
pub unsafe fn start_on_chip() -> Leds<LedPin> {
    use stm32f4::stm32f405 as pac;
    // SAFETY: the blocks' fixed addresses; exclusive by the caller's contract.
    unsafe { apply_to(&*pac::RCC::ptr(), &*pac::GPIOC::ptr(), &*pac::GPIOD::ptr()) }
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
    fn the_pins_are_the_boards_and_are_driven_through_bsrr() {
        // GPIOC, GPIOD and RCC in host memory (reset values 0).
        let gpioc: &'static mut [u32; 16] = Box::leak(Box::new([0; 16]));
        let gpiod: &'static mut [u32; 16] = Box::leak(Box::new([0; 16]));
        let mut rcc = [0u32; 64];
        let (pc, pd) = (gpioc.as_mut_ptr(), gpiod.as_mut_ptr());
        // SAFETY: each array is larger than its register block, u32 aligned
        // and lives for the test; the PAC's registers are volatile cells.
        let mut leds = unsafe { apply_to(&*rcc.as_mut_ptr().cast(), &*pc.cast(), &*pd.cast()) };
        let (moder, bsrr, ahb1enr) = (0, 6, 0x30 / 4);
        // GPIOC (bit 2) and GPIOD (bit 3) clocks; PC0–PC3 and PD2 outputs (0b01).
        assert_eq!(rcc[ahb1enr], 1 << 2 | 1 << 3);
        // SAFETY: reads of the arrays the register blocks were.
        let (c, d) = unsafe { (*pc.cast::<[u32; 16]>(), *pd.cast::<[u32; 16]>()) };
        assert_eq!((c[moder], d[moder]), (0x55, 0b01 << 4));
        // Dark first: the last write to each port before the mode switch was
        // an unlit level (PC3 red right: set, high = dark; PD2 blue: reset, low = dark).
        assert_eq!((c[bsrr], d[bsrr]), (1 << 3, 1 << (2 + 16)));
        // Lighting red left (PC0, active low) resets bit 0; its neighbours are untouched.
        leds.show([false, false, false, true, false]).unwrap();
        // SAFETY: as above.
        let c = unsafe { *pc.cast::<[u32; 16]>() };
        assert_eq!(c[bsrr], 1 << 3, "the last pin written is PC3, dark (set)");
        let mut red_left = LedPin {
            // SAFETY: as above.
            port: unsafe { &*pc.cast() },
            pin: 0,
        };
        red_left.set_low().unwrap();
        // SAFETY: as above.
        assert_eq!(unsafe { (*pc.cast::<[u32; 16]>())[bsrr] }, 1 << 16);
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
