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
mod target {
    use core::panic::PanicInfo;
    use cortex_m_rt::{entry, exception};
    use cortex_m_semihosting::debug;
    #[cfg(feature = "log-rtt")]
    use defmt_rtt as _;
    use fc_loop::{FcConfig, FlightCore};
    use fc_proto::{Counters, PROTOCOL_VERSION};
    use fc_stm32f405::{bring_up_clocks, PCLK2_HZ, SYSCLK_HZ};
    use hal_shim::stm32f405::{SysTickClock, Usart1};

    // Log lines carry the SysTick time in µs.
    defmt::timestamp!("{=u64:us}", {
        hal_shim::stm32f405::ticks_now() / u64::from(SYSCLK_HZ / 1_000_000)
    });

    /// defmt's global logger over semihosting (QEMU's stdout): defmt frames
    /// (rzCOBS-encoded) written with SYS_WRITE to the host's `:tt`. Used under
    /// QEMU; on hardware the `log-rtt` feature selects RTT instead.
    #[cfg(all(feature = "log-semihosting", not(feature = "log-rtt")))]
    mod semihosting_logger {
        use core::cell::RefCell;
        use core::sync::atomic::{AtomicBool, Ordering};
        use cortex_m::interrupt::Mutex;
        use cortex_m_semihosting::hio::{self, HostStream};

        #[defmt::global_logger]
        struct Logger;

        struct State {
            encoder: defmt::Encoder,
            out: Option<HostStream>,
        }

        static STATE: Mutex<RefCell<State>> = Mutex::new(RefCell::new(State {
            encoder: defmt::Encoder::new(),
            out: None,
        }));
        static TAKEN: AtomicBool = AtomicBool::new(false);
        static mut RESTORE: critical_section::RestoreState = critical_section::RestoreState::invalid();

        fn with(f: impl FnOnce(&mut State, &mut dyn FnMut(&[u8]))) {
            // SAFETY: only called between acquire and release, inside the
            // critical section that acquire entered.
            let cs = unsafe { cortex_m::interrupt::CriticalSection::new() };
            let mut st = STATE.borrow(&cs).borrow_mut();
            if st.out.is_none() {
                st.out = hio::hstdout().ok();
            }
            let mut out = st.out.take();
            let mut write = |b: &[u8]| {
                if let Some(o) = out.as_mut() {
                    let _ = o.write_all(b);
                }
            };
            f(&mut st, &mut write);
            st.out = out;
        }

        // SAFETY: acquire/release bracket every frame inside one critical
        // section; re-entry (logging from an interrupt during a frame) is
        // refused by TAKEN instead of corrupting the frame.
        unsafe impl defmt::Logger for Logger {
            fn acquire() {
                // SAFETY: paired with the release below.
                let restore = unsafe { critical_section::acquire() };
                if TAKEN.swap(true, Ordering::Relaxed) {
                    // SAFETY: undo the nested acquire.
                    unsafe { critical_section::release(restore) };
                    return;
                }
                // SAFETY: inside the critical section.
                unsafe { RESTORE = restore };
                with(|st, w| st.encoder.start_frame(w));
            }
            unsafe fn flush() {}
            unsafe fn release() {
                with(|st, w| st.encoder.end_frame(w));
                TAKEN.store(false, Ordering::Relaxed);
                // SAFETY: paired with acquire; RESTORE was set there.
                unsafe { critical_section::release(RESTORE) };
            }
            unsafe fn write(bytes: &[u8]) {
                with(|st, w| st.encoder.write(bytes, w));
            }
        }
    }

    /// Logs what changed in the link and failsafe state since the last call.
    fn log_changes(fc: &FlightCore, last: &mut (bool, bool, Counters, u32)) {
        let (session, failsafe, counters, ctrl) = (fc.session_open(), fc.failsafe(), fc.counters(), fc.selections());
        if session && !last.0 {
            defmt::info!("session open (protocol v{=u16})", PROTOCOL_VERSION);
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
        let bad =
            |c: &Counters| c.bad_crc + c.bad_cobs + c.bad_message + c.oversized + c.out_of_order + c.invalid_values;
        if bad(&counters) != bad(&last.2) {
            defmt::warn!(
                "link errors: crc {=u32} cobs {=u32} message {=u32} oversized {=u32} order {=u32} values {=u32}",
                counters.bad_crc,
                counters.bad_cobs,
                counters.bad_message,
                counters.oversized,
                counters.out_of_order,
                counters.invalid_values
            );
        }
        *last = (session, failsafe, counters, ctrl);
    }

    #[entry]
    fn main() -> ! {
        // The clock tree first: every rate below assumes 168 MHz. A board
        // whose crystal or PLL does not start would run every timer and the
        // UART at the wrong rate; it refuses to fly instead.
        if let Err(e) = bring_up_clocks() {
            defmt::error!("clock tree bring-up failed: {=str}; not flying", e.reason());
            debug::exit(debug::EXIT_FAILURE);
            loop {
                cortex_m::asm::wfi();
            }
        }
        let clock = SysTickClock::start(SYSCLK_HZ);
        let mut usart = Usart1::init(PCLK2_HZ, 115_200);
        let Some(fc) = flight_core() else {
            defmt::error!("flight loop already taken");
            debug::exit(debug::EXIT_FAILURE);
            loop {
                cortex_m::asm::wfi();
            }
        };
        if fc.start().is_err() {
            defmt::error!("boot controller design failed");
            debug::exit(debug::EXIT_FAILURE);
            loop {
                cortex_m::asm::wfi();
            }
        }
        defmt::info!("up: protocol v{=u16}, waiting on USART1", PROTOCOL_VERSION);
        let mut tx_errors: u32 = 0;
        let mut last = (false, false, Counters::default(), 0u32);
        loop {
            let now_us = clock.ticks() / u64::from(SYSCLK_HZ / 1_000_000);
            if fc.service(&mut usart, &clock, now_us).is_err() {
                tx_errors = tx_errors.wrapping_add(1);
                defmt::warn!("USART1 transmit timed out ({=u32} so far)", tx_errors);
            }
            log_changes(fc, &mut last);
            // Idle until the next interrupt (a received byte or a SysTick wrap).
            // Interrupts are masked across the check and WFI: a byte arriving
            // in between leaves its interrupt pending, which makes WFI return at
            // once, so no wake-up is lost; the handler runs when the mask lifts.
            // Under QEMU a halted CPU lets the emulator deliver the next byte
            // without executing guest instructions (so idle time does not
            // count as instructions).
            cortex_m::interrupt::free(|_| {
                if !hal_shim::stm32f405::rx_pending() {
                    cortex_m::asm::wfi();
                }
            });
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

    /// SysTick wrap: extends the 24-bit counter to 64 bits.
    #[exception]
    fn SysTick() {
        hal_shim::stm32f405::systick_isr();
    }

    /// Every device interrupt lands here; USART1's moves bytes into the queue.
    #[exception]
    unsafe fn DefaultHandler(irqn: i16) {
        if irqn == hal_shim::stm32f405::USART1_IRQ as i16 {
            hal_shim::stm32f405::usart1_isr();
        }
    }

    #[panic_handler]
    fn panic(info: &PanicInfo) -> ! {
        // The core never panics on input; if anything does, say where.
        if let Some(l) = info.location() {
            defmt::error!("panic at {=str}:{=u32}", l.file(), l.line());
        } else {
            defmt::error!("panic");
        }
        debug::exit(debug::EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("firmware: this binary is the STM32F405 image; build it with --target thumbv7em-none-eabihf");
}
