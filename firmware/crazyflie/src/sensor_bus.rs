//! The sensors' bus and data-ready line on the chip: I2C3 on PA8 (SCL) and
//! PC9 (SDA), both AF4 open-drain (the board has the pull-ups), and the
//! BMI088 gyroscope's INT3 on PC14 as EXTI14 on its rising edge (the part
//! drives it push-pull, active high: [`crate::bmi088`]'s configuration).
//! Pins and functions are [`crate::pins`]'; registers per RM0090 §7.3
//! (RCC), §8.4 (GPIO), §9.2 (SYSCFG), §12.3 (EXTI).

use stm32f4::stm32f405::{exti, gpioa, gpioc, rcc, syscfg};

/// EXTI line of the gyroscope's data-ready (PC14).
pub const DATA_READY_LINE: u8 = 14;

/// Clocks on (GPIOA, GPIOC, I2C3, SYSCFG), PA8/PC9 to I2C3, PC14 an input
/// routed to EXTI14 on its rising edge, unmasked (its pending bit cleared).
pub fn apply_to(
    rcc: &rcc::RegisterBlock,
    gpioa: &gpioa::RegisterBlock,
    gpioc: &gpioc::RegisterBlock,
    syscfg: &syscfg::RegisterBlock,
    exti: &exti::RegisterBlock,
) {
    rcc.ahb1enr().modify(|_, w| w.gpioaen().enabled().gpiocen().enabled());
    rcc.apb1enr().modify(|_, w| w.i2c3en().enabled());
    rcc.apb2enr().modify(|_, w| w.syscfgen().enabled());
    // Open-drain and the function chosen before the pins switch over.
    gpioa.otyper().modify(|_, w| w.ot(8).open_drain());
    gpioa.ospeedr().modify(|_, w| w.ospeedr(8).high_speed());
    gpioa.pupdr().modify(|_, w| w.pupdr(8).floating());
    // AFRH holds pins 8–15: PA8 is its field 0.
    gpioa.afrh().modify(|_, w| w.afr(0).af4());
    gpioa.moder().modify(|_, w| w.moder(8).alternate());
    gpioc.otyper().modify(|_, w| w.ot(9).open_drain());
    gpioc.ospeedr().modify(|_, w| w.ospeedr(9).high_speed());
    gpioc.pupdr().modify(|_, w| w.pupdr(9).floating().pupdr(14).floating());
    gpioc.afrh().modify(|_, w| w.afr(9 - 8).af4());
    gpioc.moder().modify(|_, w| w.moder(9).alternate().moder(14).input());
    // EXTI14 from port C (EXTICR4 bits 11–8 = 0b0010), rising edge.
    // SAFETY: 2 is port C's code in the 4-bit field.
    syscfg.exticr4().modify(|_, w| unsafe { w.exti14().bits(0b0010) });
    exti.rtsr().modify(|_, w| w.tr14().enabled());
    exti.ftsr().modify(|_, w| w.tr14().disabled());
    clear_data_ready(exti);
    exti.imr().modify(|_, w| w.mr14().unmasked());
}

/// Clears EXTI14's pending bit (the data-ready's interrupt, first act).
pub fn clear_data_ready(exti: &exti::RegisterBlock) {
    // PR is write-1-to-clear: only line 14's bit is written.
    exti.pr().write(|w| w.pr14().clear());
}

/// On the chip: [`apply_to`] on the real blocks; returns I2C3's registers
/// and EXTI's.
///
/// # Safety
/// The caller is the only code that touches I2C3, SYSCFG.EXTICR4, EXTI14
/// and these pins (the image's start-up, once), and nothing else
/// read-modify-writes GPIOA or GPIOC at the same time.
#[cfg(target_os = "none")]
pub unsafe fn start_on_chip() -> (
    &'static stm32f4::stm32f405::i2c1::RegisterBlock,
    &'static exti::RegisterBlock,
) {
    use stm32f4::stm32f405 as pac;
    // SAFETY: the blocks' fixed addresses; exclusive by the caller's contract.
    let (rcc, gpioa, gpioc, syscfg, exti, i2c3) = unsafe {
        (
            &*pac::RCC::ptr(),
            &*pac::GPIOA::ptr(),
            &*pac::GPIOC::ptr(),
            &*pac::SYSCFG::ptr(),
            &*pac::EXTI::ptr(),
            &*pac::I2C3::ptr(),
        )
    };
    apply_to(rcc, gpioa, gpioc, syscfg, exti);
    (i2c3, exti)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The blocks in host memory: RCC, GPIOA (its reset MODER: PA13–15
    /// debug; PUPDR: PA15 up, PA14 down, PA13 up), GPIOC, SYSCFG, EXTI.
    struct FakeChip {
        rcc: [u32; 64],
        gpioa: [u32; 16],
        gpioc: [u32; 16],
        syscfg: [u32; 16],
        exti: [u32; 8],
    }

    const AHB1ENR: usize = 0x30 / 4;
    const APB1ENR: usize = 0x40 / 4;
    const APB2ENR: usize = 0x44 / 4;
    const MODER: usize = 0;
    const OTYPER: usize = 1;
    const OSPEEDR: usize = 2;
    const PUPDR: usize = 3;
    const AFRH: usize = 9;
    const EXTICR4: usize = 0x14 / 4;
    const IMR: usize = 0;
    const RTSR: usize = 2;
    const FTSR: usize = 3;
    const PR: usize = 5;

    #[test]
    fn the_bus_and_the_data_ready_line_get_rm0090s_values() {
        let mut c = FakeChip {
            rcc: [0; 64],
            gpioa: [0; 16],
            gpioc: [0; 16],
            syscfg: [0; 16],
            exti: [0; 8],
        };
        c.gpioa[MODER] = 0xA800_0000;
        c.gpioa[PUPDR] = 0x6400_0000;
        c.exti[FTSR] = 1 << 14;
        assert!(core::mem::size_of::<rcc::RegisterBlock>() <= 4 * 64);
        assert!(core::mem::size_of::<gpioa::RegisterBlock>() <= 4 * 16);
        assert!(core::mem::size_of::<syscfg::RegisterBlock>() <= 4 * 16);
        assert!(core::mem::size_of::<exti::RegisterBlock>() <= 4 * 8);
        // SAFETY: each array is at least its block's size, u32 aligned and
        // borrowed mutably for the call; the registers are volatile cells.
        unsafe {
            apply_to(
                &*c.rcc.as_mut_ptr().cast(),
                &*c.gpioa.as_mut_ptr().cast(),
                &*c.gpioc.as_mut_ptr().cast(),
                &*c.syscfg.as_mut_ptr().cast(),
                &*c.exti.as_mut_ptr().cast(),
            );
        }
        // RCC: GPIOA, GPIOC (AHB1ENR bits 0, 2); I2C3 (APB1ENR bit 23); SYSCFG (APB2ENR bit 14).
        assert_eq!(
            (c.rcc[AHB1ENR], c.rcc[APB1ENR], c.rcc[APB2ENR]),
            (0b101, 1 << 23, 1 << 14)
        );
        // PA8: alternate (0b10 at bits 17–16), open-drain, fast (0b10), no
        // pull, AF4 (AFRH bits 3–0); the debug pins untouched.
        assert_eq!(c.gpioa[MODER], 0xA800_0000 | 0b10 << 16);
        assert_eq!((c.gpioa[OTYPER], c.gpioa[OSPEEDR]), (1 << 8, 0b10 << 16));
        assert_eq!((c.gpioa[PUPDR], c.gpioa[AFRH]), (0x6400_0000, 4));
        // PC9: the same (AFRH bits 7–4); PC14 an input (0b00), no pull.
        assert_eq!(c.gpioc[MODER], 0b10 << 18);
        assert_eq!((c.gpioc[OTYPER], c.gpioc[OSPEEDR]), (1 << 9, 0b10 << 18));
        assert_eq!((c.gpioc[PUPDR], c.gpioc[AFRH]), (0, 4 << 4));
        // EXTI14 from port C (EXTICR4 bits 11–8 = 2), rising only, unmasked,
        // its pending bit written 1 (cleared).
        assert_eq!(c.syscfg[EXTICR4], 2 << 8);
        assert_eq!((c.exti[RTSR], c.exti[FTSR], c.exti[IMR]), (1 << 14, 0, 1 << 14));
        assert_eq!(c.exti[PR], 1 << 14);
    }
}
