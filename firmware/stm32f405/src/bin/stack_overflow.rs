//! A deliberate stack overflow, for the fault test (`tests/tests/qemu.rs`):
//! the board's own handlers (`fc_stm32f405::board`), the motors running on TIM3, a
//! canary in `.bss`, then a recursion without end. Linked with flip-link,
//! the stack sits at the bottom of RAM, beneath every static: the overflow
//! runs off 0x2000_0000 into unmapped memory and faults, the canary above
//! is never reached, and the fault handler (on a fresh stack) turns the
//! motors off and says so.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
fc_stm32f405::board_runtime!();

#[cfg(target_os = "none")]
mod target {
    use core::sync::atomic::{AtomicU32, Ordering};
    use cortex_m_rt::entry;
    use fc_stm32f405::board;
    use fc_stm32f405::APB1_TIMER_CLK_HZ;
    use hal_shim::stm32f405::PwmActuators;
    use hal_shim::ActuatorOutput;

    /// A static the overflow must not reach (it is above the stack).
    static CANARY: [AtomicU32; 8] = [const { AtomicU32::new(0) }; 8];
    /// How deep the recursion got (the last value the stack held).
    static DEPTH: AtomicU32 = AtomicU32::new(0);

    #[inline(never)]
    fn deeper(n: u32) -> u32 {
        // 256 bytes a frame, kept alive through the call.
        let frame = core::hint::black_box([n; 64]);
        DEPTH.store(n, Ordering::Relaxed);
        if n.is_multiple_of(64) {
            for c in &CANARY {
                if c.load(Ordering::Relaxed) != 0xC0FF_EE00 {
                    board::fail("the canary changed: the stack overwrote a static");
                }
            }
        }
        deeper(n + 1).wrapping_add(frame[(n % 64) as usize])
    }

    #[entry]
    fn main() -> ! {
        let (_clock, _usart) = board::bring_up();
        for c in &CANARY {
            c.store(0xC0FF_EE00, Ordering::Relaxed);
        }
        let mut pwm = PwmActuators::start(APB1_TIMER_CLK_HZ, 400, |u| *u);
        pwm.apply([0.5; 4]);
        let (_, ccr) = pwm.registers();
        defmt::info!(
            "stack-overflow: motors running (TIM3 compare {}), stack {=usize} B from {=usize:#010x} down",
            ccr,
            fc_stm32f405::stack::capacity(),
            fc_stm32f405::stack::start()
        );
        let r = deeper(0);
        defmt::error!("stack-overflow: the recursion returned {=u32}", r);
        board::fail("no overflow")
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("stack-overflow runs on the MCU: cargo run --release -p fc-stm32f405 --bin stack-overflow --target thumbv7em-none-eabihf");
}
