//! The board glue both images share (`firmware`, our protocol, and
//! `firmware-mavlink`): defmt's logger and timestamps, the SysTick and
//! USART1 interrupt handlers, the panic handler, bring-up of the clock
//! tree, SysTick and USART1, and the idle wait. Included by each binary
//! (`#[path]`), not the library: the handlers are link-time symbols, and
//! the QEMU harness programs define their own.

use core::panic::PanicInfo;
use cortex_m_rt::exception;
use cortex_m_semihosting::debug;
#[cfg(feature = "log-rtt")]
use defmt_rtt as _;
use fc_stm32f405::{bring_up_clocks, PCLK2_HZ, SYSCLK_HZ};
use hal_shim::stm32f405::{Port, SysTickClock, Usart};

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

/// Logs `why` and ends: QEMU exits with failure; a board halts (motors off).
pub fn fail(why: &str) -> ! {
    defmt::error!("{=str}; not flying", why);
    debug::exit(debug::EXIT_FAILURE);
    loop {
        cortex_m::asm::wfi();
    }
}

/// The clock tree first (every rate assumes 168 MHz: a board whose
/// crystal or PLL does not start would run every timer and the UART at the
/// wrong rate; it refuses to fly instead), then SysTick and USART1.
pub fn bring_up() -> (SysTickClock, Usart) {
    if let Err(e) = bring_up_clocks() {
        defmt::error!("clock tree bring-up failed: {=str}", e.reason());
        fail("no clock");
    }
    (
        SysTickClock::start(SYSCLK_HZ),
        Usart::init(Port::Usart1, PCLK2_HZ, 115_200),
    )
}

/// The loop's clock, µs since boot.
#[allow(dead_code, reason = "firmware-crtp keeps the time of its IMU samples instead")]
pub fn now_us(clock: &SysTickClock) -> u64 {
    clock.ticks() / u64::from(SYSCLK_HZ / 1_000_000)
}

/// Idles until the next interrupt (a received byte or a SysTick wrap).
/// Interrupts are masked across the check and WFI: a byte arriving in
/// between leaves its interrupt pending, which makes WFI return at once, so
/// no wake-up is lost; the handler runs when the mask lifts. Under QEMU a
/// halted CPU lets the emulator deliver the next byte without executing
/// guest instructions (so idle time does not count as instructions).
pub fn idle() {
    cortex_m::interrupt::free(|_| {
        if !hal_shim::stm32f405::rx_pending() {
            cortex_m::asm::wfi();
        }
    });
}

/// SysTick wrap: extends the 24-bit counter to 64 bits.
#[exception]
fn SysTick() {
    hal_shim::stm32f405::systick_isr();
}

/// Every device interrupt lands here; a USART's moves bytes into its queue.
#[exception]
unsafe fn DefaultHandler(irqn: i16) {
    if let Some(port) = Port::of_irq(irqn) {
        hal_shim::stm32f405::usart_isr(port);
    }
}

/// A fault (bad access, stack overflow into the guard, undefined
/// instruction): says where, then ends as [`fail`] does (QEMU exits with
/// failure; a board halts with the motors off).
#[exception]
unsafe fn HardFault(ef: &cortex_m_rt::ExceptionFrame) -> ! {
    let ccr = hal_shim::stm32f405::motors_off_now();
    defmt::error!(
        "hard fault at pc {=u32:#010x} (lr {=u32:#010x}); motors off (TIM3 compare {})",
        ef.pc(),
        ef.lr(),
        ccr
    );
    fail("hard fault")
}

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    hal_shim::stm32f405::motors_off_now();
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
