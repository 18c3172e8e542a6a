//! STM32F405 image of the flight-control core (`thumbv7em-none-eabihf`).
//!
//! Boots, opens USART1, and runs the flight controller's loop
//! ([`fc_loop::FlightCore`]): frames in, controller step, frames out,
//! failsafe timer. Time is SysTick at 168 MHz, widened in software; under
//! QEMU's `-icount shift=0` one instruction is one nanosecond of virtual time,
//! so SysTick counts 0.168 per instruction. It logs through defmt: boot, the
//! handshake, controller selections, failsafe entries and exits, and link
//! errors as they happen — over semihosting by default (QEMU; `sil-host fly
//! --target qemu --firmware-log` decodes it), over RTT with the `log-rtt`
//! feature. On the host this file compiles to an empty program so that
//! `cargo build --workspace` works everywhere.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod board;

#[cfg(target_os = "none")]
mod target {
    use crate::board;
    use cortex_m_rt::entry;
    use fc_loop::{FcConfig, FlightCore};
    use fc_proto::{Counters, PROTOCOL_VERSION};
    use fc_stm32f405::log_changes;

    #[entry]
    fn main() -> ! {
        let (clock, mut usart) = board::bring_up();
        let Some(fc) = flight_core() else {
            board::fail("flight loop already taken");
        };
        if fc.start().is_err() {
            board::fail("boot controller design failed");
        }
        defmt::info!("up: protocol v{=u16}, waiting on USART1", PROTOCOL_VERSION);
        let mut tx_errors: u32 = 0;
        let mut last = (false, false, Counters::default(), 0u32);
        loop {
            let now_us = board::now_us(&clock);
            if fc.service(&mut usart, &clock, now_us).is_err() {
                tx_errors = tx_errors.wrapping_add(1);
                defmt::warn!("USART1 transmit timed out ({=u32} so far)", tx_errors);
            }
            log_changes(fc, &mut last);
            board::idle();
        }
    }

    /// The flight loop, in static RAM (its controller is ≈ 7 KiB), built
    /// once and unstarted: the boot controller is designed in place by
    /// `start`, after this frame is gone, so the design's stack is not
    /// beneath a copy of the loop.
    #[inline(never)]
    fn flight_core() -> Option<&'static mut FlightCore> {
        cortex_m::singleton!(: FlightCore = FlightCore::unstarted(FcConfig::default()))
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("firmware: this binary is the STM32F405 image; build it with --target thumbv7em-none-eabihf");
}
