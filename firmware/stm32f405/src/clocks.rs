//! Board bring-up: the STM32F405's clock tree.
//!
//! The chip boots on its 16 MHz internal oscillator (HSI). A flight
//! controller runs it at its 168 MHz maximum from the board's crystal (HSE,
//! 8 MHz on most F405 flight controllers and on the STM32F4-Discovery):
//!
//! ```text
//! HSE 8 MHz ─ /M 8 ─ 1 MHz ─ ×N 336 ─ VCO 336 MHz ─┬─ /P 2 ─ SYSCLK 168 MHz ─ AHB /1 ─ HCLK 168 MHz
//!                                                  │                             ├─ APB1 /4 ─ 42 MHz (timers ×2: 84 MHz)
//!                                                  └─ /Q 7 ─ 48 MHz (USB, SDIO)  └─ APB2 /2 ─ 84 MHz (USART1; timers 168 MHz)
//! ```
//!
//! with 5 flash wait states (RM0090 table 10: HCLK 150–168 MHz at 2.7–3.6 V),
//! prefetch and both caches (the "ART accelerator") on. [`ClockPlan`] holds
//! those numbers and checks them against the reference manual's limits on
//! any host; `ClockPlan::apply` (MCU only; [`ClockPlan::apply_to`] on any
//! register blocks) programs RCC and FLASH through the `stm32f4` PAC and
//! waits for every ready flag a bounded number of polls, returning an error
//! instead of hanging.
//!
//! QEMU's `netduinoplus2` does not model the RCC (its ready flags never set)
//! and runs the core at 168 MHz regardless. The image therefore has a
//! `qemu` feature (on by default, since QEMU is where this project runs it):
//! with it the image skips the sequence; without it (`--no-default-features
//! --features log-rtt`, the hardware build) it runs the sequence, and if the
//! crystal or the PLL does not start it stays on the HSI and reports that.

/// The STM32F405's datasheet and RM0090 limits the plan is checked against.
pub mod limits {
    /// Most SYSCLK/HCLK, Hz.
    pub const SYSCLK_MAX_HZ: u32 = 168_000_000;
    /// Most APB1 clock, Hz.
    pub const PCLK1_MAX_HZ: u32 = 42_000_000;
    /// Most APB2 clock, Hz.
    pub const PCLK2_MAX_HZ: u32 = 84_000_000;
    /// PLL input (after /M), Hz: 1–2 MHz (2 MHz recommended for jitter).
    pub const PLL_IN_HZ: (u32, u32) = (1_000_000, 2_000_000);
    /// VCO output, Hz.
    pub const VCO_HZ: (u32, u32) = (100_000_000, 432_000_000);
    /// HCLK per flash wait state at 2.7–3.6 V, Hz (RM0090 table 10).
    pub const HZ_PER_WAIT_STATE: u32 = 30_000_000;
    /// USB OTG FS needs exactly this from /Q, Hz.
    pub const USB_HZ: u32 = 48_000_000;
}

/// A clock tree: the crystal, the PLL factors, the bus prescalers and the
/// flash wait states.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockPlan {
    /// External crystal, Hz.
    pub hse_hz: u32,
    /// PLL input divider M (2–63).
    pub pllm: u8,
    /// VCO multiplier N (50–432).
    pub plln: u16,
    /// SYSCLK divider P (2, 4, 6 or 8).
    pub pllp: u8,
    /// 48 MHz-domain divider Q (2–15).
    pub pllq: u8,
    /// AHB prescaler (1, 2, 4, …, 512).
    pub ahb_div: u16,
    /// APB1 prescaler (1, 2, 4, 8, 16).
    pub apb1_div: u8,
    /// APB2 prescaler (1, 2, 4, 8, 16).
    pub apb2_div: u8,
    /// Flash wait states (0–7).
    pub flash_wait_states: u8,
}

/// Why a clock plan was refused or could not be applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClockError {
    /// The plan breaks a limit of the chip (which one is named).
    InvalidPlan(&'static str),
    /// The crystal did not report ready within the poll bound.
    HseTimeout,
    /// The PLL did not lock within the poll bound.
    PllTimeout,
    /// The system clock switch to the PLL was not confirmed within the poll bound.
    SwitchTimeout,
}

impl ClockError {
    /// What went wrong, as a static string (defmt logs `str`, not `Display`).
    pub const fn reason(&self) -> &'static str {
        match self {
            ClockError::InvalidPlan(why) => why,
            ClockError::HseTimeout => "HSE crystal not ready (no crystal, or QEMU, which has no RCC model)",
            ClockError::PllTimeout => "PLL did not lock",
            ClockError::SwitchTimeout => "system clock did not switch to the PLL",
        }
    }
}

impl core::fmt::Display for ClockError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        if let ClockError::InvalidPlan(_) = self {
            f.write_str("clock plan refused: ")?;
        }
        f.write_str(self.reason())
    }
}

impl core::error::Error for ClockError {}

impl ClockPlan {
    /// 168 MHz from an 8 MHz crystal (see the module docs).
    pub const F405_168MHZ_FROM_8MHZ: ClockPlan = ClockPlan {
        hse_hz: 8_000_000,
        pllm: 8,
        plln: 336,
        pllp: 2,
        pllq: 7,
        ahb_div: 1,
        apb1_div: 4,
        apb2_div: 2,
        flash_wait_states: 5,
    };

    /// VCO output, Hz.
    pub const fn vco_hz(&self) -> u32 {
        self.hse_hz / self.pllm as u32 * self.plln as u32
    }
    /// SYSCLK, Hz.
    pub const fn sysclk_hz(&self) -> u32 {
        self.vco_hz() / self.pllp as u32
    }
    /// HCLK (core, AHB, SysTick, DWT), Hz.
    pub const fn hclk_hz(&self) -> u32 {
        self.sysclk_hz() / self.ahb_div as u32
    }
    /// APB1 peripheral clock, Hz.
    pub const fn pclk1_hz(&self) -> u32 {
        self.hclk_hz() / self.apb1_div as u32
    }
    /// APB2 peripheral clock (USART1), Hz.
    pub const fn pclk2_hz(&self) -> u32 {
        self.hclk_hz() / self.apb2_div as u32
    }
    /// Clock of the APB1 timers (TIM2–5), Hz: twice PCLK1 when APB1 is divided.
    pub const fn apb1_timer_hz(&self) -> u32 {
        if self.apb1_div == 1 {
            self.pclk1_hz()
        } else {
            2 * self.pclk1_hz()
        }
    }
    /// The 48 MHz domain (USB, SDIO), Hz.
    pub const fn pll48_hz(&self) -> u32 {
        self.vco_hz() / self.pllq as u32
    }

    /// Checks the plan against the chip's limits ([`limits`]).
    pub fn check(&self) -> Result<(), ClockError> {
        use limits::*;
        let bad = ClockError::InvalidPlan;
        if !(2..=63).contains(&self.pllm) || !self.hse_hz.is_multiple_of(u32::from(self.pllm)) {
            return Err(bad("PLL M must be 2..=63 and divide the crystal frequency"));
        }
        let pll_in = self.hse_hz / u32::from(self.pllm);
        if !(PLL_IN_HZ.0..=PLL_IN_HZ.1).contains(&pll_in) {
            return Err(bad("PLL input (HSE / M) must be 1..=2 MHz"));
        }
        if !(50..=432).contains(&self.plln) || !(VCO_HZ.0..=VCO_HZ.1).contains(&self.vco_hz()) {
            return Err(bad("VCO (input x N) must be 100..=432 MHz with N 50..=432"));
        }
        if !matches!(self.pllp, 2 | 4 | 6 | 8) {
            return Err(bad("PLL P must be 2, 4, 6 or 8"));
        }
        if !(2..=15).contains(&self.pllq) {
            return Err(bad("PLL Q must be 2..=15"));
        }
        self.prescaler_bits()?;
        if self.sysclk_hz() > SYSCLK_MAX_HZ {
            return Err(bad("SYSCLK above 168 MHz"));
        }
        if self.pclk1_hz() > PCLK1_MAX_HZ {
            return Err(bad("APB1 above 42 MHz"));
        }
        if self.pclk2_hz() > PCLK2_MAX_HZ {
            return Err(bad("APB2 above 84 MHz"));
        }
        if self.flash_wait_states > 7
            || u32::from(self.flash_wait_states) < self.hclk_hz().div_ceil(HZ_PER_WAIT_STATE) - 1
        {
            return Err(bad("too few flash wait states for HCLK (RM0090 table 10, 2.7-3.6 V)"));
        }
        Ok(())
    }

    /// RCC_CFGR.HPRE's encoding of [`ClockPlan::ahb_div`] (RM0090 §7.3.3).
    pub const fn ahb_prescaler_bits(&self) -> Option<u8> {
        Some(match self.ahb_div {
            1 => 0b0000,
            2 => 0b1000,
            4 => 0b1001,
            8 => 0b1010,
            16 => 0b1011,
            64 => 0b1100,
            128 => 0b1101,
            256 => 0b1110,
            512 => 0b1111,
            _ => return None,
        })
    }

    /// RCC_CFGR's HPRE, PPRE1 and PPRE2 fields for this plan, or which
    /// divider has no encoding.
    fn prescaler_bits(&self) -> Result<(u8, u8, u8), ClockError> {
        let bad = ClockError::InvalidPlan;
        let hpre = self
            .ahb_prescaler_bits()
            .ok_or(bad("AHB must be divided by 1, 2, 4, 8, 16, 64, 128, 256 or 512"))?;
        let ppre1 = Self::apb_prescaler_bits(self.apb1_div).ok_or(bad("APB1 must be divided by 1, 2, 4, 8 or 16"))?;
        let ppre2 = Self::apb_prescaler_bits(self.apb2_div).ok_or(bad("APB2 must be divided by 1, 2, 4, 8 or 16"))?;
        Ok((hpre, ppre1, ppre2))
    }

    /// RCC_CFGR.PPREx's encoding of an APB divider (RM0090 §7.3.3).
    pub const fn apb_prescaler_bits(div: u8) -> Option<u8> {
        Some(match div {
            1 => 0b000,
            2 => 0b100,
            4 => 0b101,
            8 => 0b110,
            16 => 0b111,
            _ => return None,
        })
    }

    /// RCC_PLLCFGR.PLLP's encoding of [`ClockPlan::pllp`]: P = 2·(bits + 1).
    pub const fn pllp_bits(&self) -> u8 {
        self.pllp / 2 - 1
    }

    /// Programs the clock tree (RCC and FLASH through the PAC): HSE on, PLL
    /// configured and locked, wait states and the ART accelerator, bus
    /// prescalers, switch to the PLL. Every wait is bounded by `polls`
    /// reads; a flag that does not come is an error, and the chip is then
    /// still on its 16 MHz HSI (nothing is switched before the PLL locks).
    ///
    /// Call once at boot, before any peripheral driver starts.
    #[cfg(target_os = "none")]
    pub fn apply(&self, polls: u32) -> Result<(), ClockError> {
        use stm32f4::stm32f405 as pac;
        // SAFETY: the PAC's handles to RCC and FLASH; bring-up runs once,
        // before anything else touches them.
        let (rcc, flash) = unsafe { (&*pac::RCC::ptr(), &*pac::FLASH::ptr()) };
        self.apply_to(rcc, flash, polls)
    }

    /// The sequence of `ClockPlan::apply` (MCU only) on the given RCC and FLASH
    /// register blocks: the chip's on the MCU, RAM-backed ones in the host
    /// tests, which check the values it writes against RM0090's encodings
    /// and what it leaves untouched when a flag never comes.
    pub fn apply_to(
        &self,
        rcc: &stm32f4::stm32f405::rcc::RegisterBlock,
        flash: &stm32f4::stm32f405::flash::RegisterBlock,
        polls: u32,
    ) -> Result<(), ClockError> {
        self.check()?;
        let (hpre, ppre1, ppre2) = self.prescaler_bits()?;
        let wait = |ready: &dyn Fn() -> bool, e: ClockError| {
            for _ in 0..polls {
                if ready() {
                    return Ok(());
                }
            }
            Err(e)
        };
        rcc.cr().modify(|_, w| w.hseon().on());
        wait(&|| rcc.cr().read().hserdy().is_ready(), ClockError::HseTimeout)?;
        // SAFETY: M, N, P and Q were range-checked by `check` above.
        rcc.pllcfgr().write(|w| unsafe {
            w.pllsrc()
                .hse()
                .pllm()
                .bits(self.pllm)
                .plln()
                .bits(self.plln)
                .pllq()
                .bits(self.pllq)
                .pllp()
                .bits(self.pllp_bits())
        });
        rcc.cr().modify(|_, w| w.pllon().on());
        wait(&|| rcc.cr().read().pllrdy().is_ready(), ClockError::PllTimeout)?;
        // Wait states before the faster clock (RM0090 §3.5.1).
        flash.acr().modify(|_, w| {
            w.latency()
                .set(self.flash_wait_states)
                .prften()
                .enabled()
                .icen()
                .enabled()
                .dcen()
                .enabled()
        });
        // SAFETY: the prescaler encodings come from RM0090 (checked above
        // and against the PAC's enumerations in the tests).
        rcc.cfgr()
            .modify(|_, w| unsafe { w.hpre().bits(hpre).ppre1().bits(ppre1).ppre2().bits(ppre2) });
        rcc.cfgr().modify(|_, w| w.sw().pll());
        wait(&|| rcc.cfgr().read().sws().is_pll(), ClockError::SwitchTimeout)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stm32f4::stm32f405::{flash::acr::LATENCY, rcc::cfgr, rcc::pllcfgr::PLLP};

    #[test]
    fn the_flight_plan_gives_the_bus_clocks_the_firmware_assumes() {
        let p = ClockPlan::F405_168MHZ_FROM_8MHZ;
        assert_eq!(p.check(), Ok(()));
        assert_eq!(
            (
                p.sysclk_hz(),
                p.hclk_hz(),
                p.pclk1_hz(),
                p.pclk2_hz(),
                p.apb1_timer_hz(),
                p.pll48_hz()
            ),
            (168_000_000, 168_000_000, 42_000_000, 84_000_000, 84_000_000, 48_000_000)
        );
        assert_eq!(p.vco_hz(), 336_000_000);
        // The image's constants are this plan's (and QEMU's netduinoplus2 runs at the same 168 MHz).
        assert_eq!(crate::CLOCKS, p);
        assert_eq!(
            (crate::SYSCLK_HZ, crate::PCLK2_HZ, crate::APB1_TIMER_CLK_HZ),
            (168_000_000, 84_000_000, 84_000_000)
        );
    }

    #[test]
    fn register_encodings_match_the_pac() {
        let p = ClockPlan::F405_168MHZ_FROM_8MHZ;
        // What `apply` writes, against the PAC's enumerated values (from ST's SVD).
        assert_eq!(p.pllp_bits(), PLLP::Div2 as u8);
        assert_eq!(p.ahb_prescaler_bits(), Some(cfgr::HPRE::Div1 as u8));
        assert_eq!(ClockPlan::apb_prescaler_bits(4), Some(cfgr::PPRE1::Div4 as u8));
        assert_eq!(ClockPlan::apb_prescaler_bits(2), Some(cfgr::PPRE1::Div2 as u8));
        assert_eq!(p.flash_wait_states, LATENCY::Ws5 as u8);
        for (div, e) in [(1, cfgr::PPRE1::Div1), (8, cfgr::PPRE1::Div8), (16, cfgr::PPRE1::Div16)] {
            assert_eq!(ClockPlan::apb_prescaler_bits(div), Some(e as u8));
        }
        for (div, e) in [
            (2, cfgr::HPRE::Div2),
            (64, cfgr::HPRE::Div64),
            (512, cfgr::HPRE::Div512),
        ] {
            assert_eq!(ClockPlan { ahb_div: div, ..p }.ahb_prescaler_bits(), Some(e as u8));
        }
        for (pp, e) in [(4, PLLP::Div4), (6, PLLP::Div6), (8, PLLP::Div8)] {
            assert_eq!(ClockPlan { pllp: pp, ..p }.pllp_bits(), e as u8);
        }
    }

    /// RCC and FLASH register blocks in host memory, at their reset values
    /// (RM0090 §7.3, §3.9), with the ready flags a test wants "set by the
    /// hardware" already set (nothing here sets them by itself: as QEMU).
    struct FakeChip {
        rcc: [u32; 64],
        flash: [u32; 16],
    }

    // Word indices of the registers (byte offsets 0x00, 0x04, 0x08; ACR 0x00).
    const CR: usize = 0;
    const PLLCFGR: usize = 1;
    const CFGR: usize = 2;
    const ACR: usize = 0;
    const HSERDY: u32 = 1 << 17;
    const PLLRDY: u32 = 1 << 25;
    const SWS_PLL: u32 = 0b10 << 2;

    impl FakeChip {
        fn new(ready: u32, sws_pll: bool) -> Self {
            let mut rcc = [0u32; 64];
            rcc[CR] = 0x0000_0083 | ready; // HSION, HSIRDY, HSITRIM = 16
            rcc[PLLCFGR] = 0x2400_3010;
            rcc[CFGR] = if sws_pll { SWS_PLL } else { 0 };
            Self { rcc, flash: [0; 16] }
        }

        fn apply(&mut self, plan: &ClockPlan) -> Result<(), ClockError> {
            use stm32f4::stm32f405::{flash, rcc};
            assert!(core::mem::size_of::<rcc::RegisterBlock>() <= core::mem::size_of_val(&self.rcc));
            assert!(core::mem::size_of::<flash::RegisterBlock>() <= core::mem::size_of_val(&self.flash));
            // SAFETY: both arrays are larger than the register blocks, u32
            // aligned, and borrowed mutably for the call; the PAC's registers
            // are volatile cells, so host memory serves as well as the chip's.
            let (r, f) = unsafe {
                (
                    &*self.rcc.as_mut_ptr().cast::<rcc::RegisterBlock>(),
                    &*self.flash.as_mut_ptr().cast::<flash::RegisterBlock>(),
                )
            };
            plan.apply_to(r, f, 1000)
        }
    }

    #[test]
    fn the_register_sequence_writes_rm0090s_values() {
        let p = ClockPlan::F405_168MHZ_FROM_8MHZ;
        let mut chip = FakeChip::new(HSERDY | PLLRDY, true);
        assert_eq!(chip.apply(&p), Ok(()));
        // RCC_CR: HSEON (16) and PLLON (24) added to the reset value.
        assert_eq!(chip.rcc[CR], 0x0000_0083 | HSERDY | PLLRDY | 1 << 16 | 1 << 24);
        // RCC_PLLCFGR: M = 8 (bits 0–5), N = 336 (6–14), P = /2 → 0b00 (16–17),
        // source HSE (22), Q = 7 (24–27); reserved bit 29 keeps its reset 1.
        assert_eq!(chip.rcc[PLLCFGR], 8 | 336 << 6 | 1 << 22 | 7 << 24 | 1 << 29);
        // RCC_CFGR: SW = PLL (0b10), HPRE /1 (0b0000), PPRE1 /4 (0b101 at 10),
        // PPRE2 /2 (0b100 at 13); SWS as the "hardware" left it.
        assert_eq!(chip.rcc[CFGR], 0b10 | SWS_PLL | 0b101 << 10 | 0b100 << 13);
        // FLASH_ACR: 5 wait states, prefetch (8), instruction (9) and data (10) caches.
        assert_eq!(chip.flash[ACR], 5 | 1 << 8 | 1 << 9 | 1 << 10);
    }

    #[test]
    fn a_flag_that_never_comes_stops_the_sequence_before_anything_is_switched() {
        let p = ClockPlan::F405_168MHZ_FROM_8MHZ;
        // No crystal: HSE on, nothing else touched, still on the HSI.
        let mut chip = FakeChip::new(0, false);
        assert_eq!(chip.apply(&p), Err(ClockError::HseTimeout));
        assert_eq!(chip.rcc[CR], 0x0000_0083 | 1 << 16);
        assert_eq!(
            (chip.rcc[PLLCFGR], chip.rcc[CFGR], chip.flash[ACR]),
            (0x2400_3010, 0, 0)
        );
        // The PLL does not lock: configured and on, but no wait states and no switch.
        let mut chip = FakeChip::new(HSERDY, false);
        assert_eq!(chip.apply(&p), Err(ClockError::PllTimeout));
        assert_eq!((chip.rcc[CFGR], chip.flash[ACR]), (0, 0));
        // The switch is not confirmed: it was requested, with the 5 wait states in place.
        let mut chip = FakeChip::new(HSERDY | PLLRDY, false);
        assert_eq!(chip.apply(&p), Err(ClockError::SwitchTimeout));
        assert_eq!(chip.flash[ACR] & 0xF, 5);
        assert_eq!(chip.rcc[CFGR] & 0b11, 0b10);
    }

    #[test]
    fn plans_that_break_a_limit_are_refused() {
        let p = ClockPlan::F405_168MHZ_FROM_8MHZ;
        let refused = |q: ClockPlan| matches!(q.check(), Err(ClockError::InvalidPlan(_)));
        assert!(
            refused(ClockPlan {
                flash_wait_states: 4,
                ..p
            }),
            "168 MHz needs 5 wait states"
        );
        assert!(refused(ClockPlan { apb1_div: 2, ..p }), "APB1 84 MHz");
        assert!(refused(ClockPlan { apb2_div: 1, ..p }), "APB2 168 MHz");
        assert!(refused(ClockPlan { plln: 360, ..p }), "SYSCLK 180 MHz");
        assert!(refused(ClockPlan { pllm: 2, ..p }), "PLL input 4 MHz");
        assert!(refused(ClockPlan { pllp: 3, ..p }), "P = 3");
        assert!(refused(ClockPlan { ahb_div: 32, ..p }), "AHB /32 does not exist");
        assert!(
            refused(ClockPlan {
                hse_hz: 25_000_000,
                ..p
            }),
            "M = 8 does not divide 25 MHz"
        );
        // A slower, valid tree: 84 MHz needs 2 wait states.
        let slow = ClockPlan {
            pllp: 4,
            apb1_div: 2,
            apb2_div: 1,
            flash_wait_states: 2,
            ..p
        };
        assert_eq!(slow.check(), Ok(()));
        assert!(refused(ClockPlan {
            flash_wait_states: 1,
            ..slow
        }));
    }
}
