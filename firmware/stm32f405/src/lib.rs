//! # fc-stm32f405 — the STM32F405 flight-controller image
//!
//! The binary `firmware` (`src/main.rs`) is the image: board bring-up
//! ([`clocks`]), then the flight loop of `fc-loop` on USART1. The harness
//! programs `budget`, `equivalence`, `drivers` and `peer` (`src/bin/`) run in QEMU.
//! This library holds what they share; its clock plan is checked on the host.
#![cfg_attr(target_os = "none", no_std)]
#![deny(missing_docs)]

#[cfg(target_os = "none")]
pub mod board;
pub mod budgets;
pub mod clocks;
#[cfg(target_os = "none")]
pub mod crtp_app;
#[cfg(target_os = "none")]
pub mod crtp_image;
pub mod equivalence;
pub mod flash;
#[cfg(target_os = "none")]
pub mod stack;
pub mod timing;
pub mod watchdog;

pub use clocks::{ClockError, ClockPlan};

/// The clock tree the image runs: 168 MHz from an 8 MHz crystal.
pub const CLOCKS: ClockPlan = ClockPlan::F405_168MHZ_FROM_8MHZ;
/// Core clock (HCLK: SysTick, DWT), Hz.
pub const SYSCLK_HZ: u32 = CLOCKS.hclk_hz();
/// APB2 peripheral clock (USART1), Hz.
pub const PCLK2_HZ: u32 = CLOCKS.pclk2_hz();
/// Clock of the APB1 timers (TIM2, TIM3), Hz.
pub const APB1_TIMER_CLK_HZ: u32 = CLOCKS.apb1_timer_hz();

/// Polls of each ready flag before the clock bring-up gives up: HSE start-up
/// is ≤ 2 ms (datasheet), ≈ 10 k polls at the 16 MHz HSI; this allows 50×.
pub const CLOCK_POLLS: u32 = 500_000;

/// Brings the clock tree up ([`CLOCKS`]); with the `qemu` feature, does
/// nothing (QEMU has no RCC model and runs at 168 MHz).
#[cfg(target_os = "none")]
pub fn bring_up_clocks() -> Result<(), ClockError> {
    if cfg!(feature = "qemu") {
        Ok(())
    } else {
        CLOCKS.apply(CLOCK_POLLS)
    }
}

/// The image's flight-loop log (used by every board's image): a line for
/// each change of session, controller, failsafe or link-error counts.
#[cfg(target_os = "none")]
pub fn log_changes(fc: &fc_loop::Loop, last: &mut (bool, bool, fc_proto::Counters, u32)) {
    let (session, failsafe, counters, ctrl) = (fc.session_open(), fc.failsafe(), fc.counters(), fc.selections());
    if session && !last.0 {
        defmt::info!("session open (protocol v{=u16})", fc_proto::PROTOCOL_VERSION);
    }
    if ctrl != last.3 {
        defmt::info!("controller selected ({=u32} so far)", ctrl);
    }
    if failsafe != last.1 {
        if failsafe {
            defmt::warn!("failsafe: no valid sensor frame in time; level, descending");
        } else {
            defmt::info!("failsafe cleared: valid sensor frames again");
        }
    }
    let bad = |c: &fc_proto::Counters| {
        c.bad_crc + c.bad_cobs + c.bad_message + c.oversized + c.out_of_order + c.invalid_values
    };
    if bad(&counters) != bad(&last.2) {
        defmt::warn!(
            "link errors: crc {=u32} cobs {=u32} message {=u32} oversized {=u32} order {=u32} values {=u32} (receiver overruns {=u32})",
            counters.bad_crc,
            counters.bad_cobs,
            counters.bad_message,
            counters.oversized,
            counters.out_of_order,
            counters.invalid_values,
            hal_shim::stm32f405::rx_overruns(hal_shim::stm32f405::Port::Usart1)
        );
    }
    *last = (session, failsafe, counters, ctrl);
}

/// Ends a QEMU harness program: exits QEMU through semihosting with
/// success (`ok`) or failure, which is the harness's verdict for its caller.
#[cfg(target_os = "none")]
pub fn harness_exit(ok: bool) -> ! {
    use cortex_m_semihosting::debug;
    debug::exit(if ok { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
    loop {
        cortex_m::asm::wfi();
    }
}

/// The runtime glue every QEMU harness program that times itself needs:
/// the SysTick handler that extends hal-shim's 64-bit clock, and a panic
/// handler that names the program and exits QEMU with failure. Use once,
/// inside the program's target module: `fc_stm32f405::harness_runtime!("budget");`.
#[cfg(target_os = "none")]
#[macro_export]
macro_rules! harness_runtime {
    ($name:literal) => {
        /// SysTick reload: extends the counter (see hal-shim).
        #[cortex_m_rt::exception]
        fn SysTick() {
            hal_shim::stm32f405::systick_isr();
        }

        #[panic_handler]
        fn panic(_: &core::panic::PanicInfo) -> ! {
            cortex_m_semihosting::hprintln!(concat!($name, ": panic"));
            $crate::harness_exit(false)
        }
    };
}
