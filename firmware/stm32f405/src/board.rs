//! The board glue every image shares: defmt's logger and timestamps,
//! bring-up of the clock tree, SysTick and USART1, the way a
//! fault stops the motors and what the fault and panic handlers say.
//!
//! The handlers themselves are link-time symbols (the vector table's
//! `SysTick`, `DefaultHandler` and `HardFault`, the panic handler), which
//! the QEMU harness programs define their own way; so an image binds them
//! with one macro, [`board_runtime!`](crate::board_runtime), and everything
//! they do is here.

use crate::{bring_up_clocks, PCLK2_HZ, SYSCLK_HZ};
use core::panic::PanicInfo;
use cortex_m_semihosting::debug;
#[cfg(feature = "log-rtt")]
use defmt_rtt as _;
use hal_shim::stm32f405::{Port, SysTickClock, Usart};

// Log lines carry the SysTick time in µs.
defmt::timestamp!("{=u64:us}", { us_of(hal_shim::stm32f405::ticks_now()) });

/// SysTick ticks (the 168 MHz core clock) as µs.
pub fn us_of(ticks: u64) -> u64 {
    ticks / u64::from(SYSCLK_HZ / 1_000_000)
}

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

/// The images' idle task: the boot's stack high-water mark logged
/// (`stack: boot reached N bytes`, [`crate::stack::boot_done`]), then
/// asleep between interrupts.
pub fn idle() -> ! {
    let boot = crate::stack::boot_done();
    defmt::info!("stack: boot reached {=usize} bytes", boot);
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
pub fn now_us(clock: &SysTickClock) -> u64 {
    us_of(clock.ticks())
}

/// What stops the motors in a fault, as a function's address: the
/// STM32F405 board's TIM3 ([`hal_shim::stm32f405::motors_off_now`]) unless
/// the image names its own at boot ([`on_fault_stop_motors`]).
static MOTORS_OFF: core::sync::atomic::AtomicUsize = core::sync::atomic::AtomicUsize::new(0);

/// Names the function that turns this board's motors off at once and
/// returns their timers' name and four compare values read back (a fault
/// handler's first act).
pub fn on_fault_stop_motors(f: fn() -> (&'static str, [u32; 4])) {
    MOTORS_OFF.store(f as usize, core::sync::atomic::Ordering::Relaxed);
}

/// Stops the motors at once (the function [`on_fault_stop_motors`]
/// named, TIM3 otherwise): the timers' name and their compare values read
/// back.
pub fn stop_motors() -> (&'static str, [u32; 4]) {
    match MOTORS_OFF.load(core::sync::atomic::Ordering::Relaxed) {
        0 => ("TIM3", hal_shim::stm32f405::motors_off_now()),
        f => {
            // SAFETY: only `on_fault_stop_motors` stores, and it stores such a function.
            let f = unsafe { core::mem::transmute::<usize, fn() -> (&'static str, [u32; 4])>(f) };
            f()
        }
    }
}

/// A fault (bad access, undefined instruction, a stack overflow): stops the
/// motors, says where (or that the stack overflowed), then ends as [`fail`]
/// does (QEMU exits with failure; a board halts with the motors off).
/// `frame` is the stacked exception frame, null when the stack overflowed;
/// `sp` the stack pointer at the fault.
///
/// # Safety
///
/// `frame` is null or points at the exception frame the processor stacked.
pub unsafe fn hard_fault(frame: *const cortex_m_rt::ExceptionFrame, sp: u32) -> ! {
    let (timers, ccr) = stop_motors();
    // SAFETY: non-null only when MSP was inside the stack, where the
    // processor stacked the frame.
    match unsafe { frame.as_ref() } {
        Some(ef) => defmt::error!(
            "hard fault at pc {=u32:#010x} (lr {=u32:#010x}); motors off ({=str} compare {})",
            ef.pc(),
            ef.lr(),
            timers,
            ccr
        ),
        None => defmt::error!(
            "stack overflow: sp {=u32:#010x} ran past the stack's end; motors off ({=str} compare {})",
            sp,
            timers,
            ccr
        ),
    }
    fail(if frame.is_null() {
        "stack overflow"
    } else {
        "hard fault"
    })
}

/// The panic handler's work: the motors off, where it panicked, then QEMU
/// exits with failure (a board halts).
pub fn panic(info: &PanicInfo) -> ! {
    stop_motors();
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

/// Binds the board glue's link-time symbols in an image (once, at its
/// crate's root, on the target): the SysTick handler (the 64-bit clock),
/// the device interrupts' default handler (the USARTs' queues), the
/// HardFault vector ([`hard_fault`]: a stack overflow caught before
/// anything is pushed) and the panic handler ([`panic`](fn@panic)). An RTIC image's
/// own tasks bind the interrupts they use; the rest land here.
#[macro_export]
macro_rules! board_runtime {
    () => {
        /// SysTick wrap: extends the 24-bit counter to 64 bits.
        #[cortex_m_rt::exception]
        fn SysTick() {
            hal_shim::stm32f405::systick_isr();
        }

        /// Every device interrupt an image does not bind lands here;
        /// USART1's (the link [`bring_up`](crate::board::bring_up) starts
        /// in every image) moves bytes into its queue. USART6 is started
        /// only by the CRTP images, whose task binds it, so an image that
        /// does not use it links no queue for it.
        #[cortex_m_rt::exception]
        unsafe fn DefaultHandler(irqn: i16) {
            if hal_shim::stm32f405::Port::of_irq(irqn) == Some(hal_shim::stm32f405::Port::Usart1) {
                hal_shim::stm32f405::usart_isr(hal_shim::stm32f405::Port::Usart1);
            }
        }

        // The HardFault vector. A stack overflow (the stack, linked by
        // flip-link beneath the statics, ran off the start of RAM) faults
        // while the processor stacks the exception frame, so the handler
        // starts with the stack pointer below the stack: any push would
        // fault again and lock the core up. This entry therefore checks MSP
        // first and, if it is below the stack's lowest address
        // (`_stack_end`), restarts the stack at its top (the overflowed
        // frames are lost anyway; nothing returns) and passes no frame.
        // Then `board_hard_fault` stops the motors and says why.
        core::arch::global_asm!(
            ".section .text.HardFault, \"ax\"",
            ".global HardFault",
            ".type HardFault, %function",
            ".thumb_func",
            "HardFault:",
            "    mrs   r1, msp",
            "    mov   r0, r1",
            "    ldr   r2, =_stack_end",
            "    cmp   r1, r2",
            "    bhs   1f",
            "    ldr   r2, =_stack_start",
            "    mov   sp, r2",
            "    movs  r0, #0",
            "1:  b     board_hard_fault",
            ".ltorg",
        );

        /// The HardFault entry's Rust half: `fc_stm32f405::board::hard_fault`.
        #[no_mangle]
        unsafe extern "C" fn board_hard_fault(frame: *const cortex_m_rt::ExceptionFrame, sp: u32) -> ! {
            // SAFETY: the entry passes the stacked frame or null.
            unsafe { $crate::board::hard_fault(frame, sp) }
        }

        #[panic_handler]
        fn panic(info: &core::panic::PanicInfo) -> ! {
            $crate::board::panic(info)
        }
    };
}
