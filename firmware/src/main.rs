//! STM32F405 image of the flight-control core (`thumbv7em-none-eabihf`).
//!
//! Boots, opens USART1, and runs the flight controller's loop
//! ([`firmware::fc::FlightCore`]): frames in, controller step, frames out,
//! failsafe timer. Time is SysTick at 168 MHz, widened in software; under
//! QEMU's `-icount shift=0` one instruction is one nanosecond of virtual time,
//! so SysTick counts 0.168 per instruction. Boot messages go out through
//! semihosting. On the host this file compiles to an empty program so that
//! `cargo build --workspace` works everywhere.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod target {
    use core::panic::PanicInfo;
    use cortex_m_rt::{entry, exception};
    use cortex_m_semihosting::{debug, hprintln};
    use firmware::fc::{FcConfig, FlightCore};
    use firmware::proto::PROTOCOL_VERSION;
    use hal_shim::stm32f405::{SysTickClock, Usart1};

    const SYSCLK_HZ: u32 = 168_000_000;
    const PCLK2_HZ: u32 = 84_000_000;

    #[entry]
    fn main() -> ! {
        let clock = SysTickClock::start(SYSCLK_HZ);
        let mut usart = Usart1::init(PCLK2_HZ, 115_200);
        let mut fc = match FlightCore::new(FcConfig::default()) {
            Ok(fc) => fc,
            Err(_) => {
                hprintln!("firmware: controller design failed");
                debug::exit(debug::EXIT_FAILURE);
                loop {
                    cortex_m::asm::wfi();
                }
            }
        };
        hprintln!("firmware: up, protocol v{}, waiting on USART1", PROTOCOL_VERSION);
        let mut tx_errors: u32 = 0;
        loop {
            let now_us = clock.ticks() / u64::from(SYSCLK_HZ / 1_000_000);
            if fc.service(&mut usart, &clock, now_us).is_err() {
                tx_errors = tx_errors.wrapping_add(1);
            }
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
    fn panic(_: &PanicInfo) -> ! {
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
