//! The STM32F405 drivers of hal-shim in QEMU: TIM2 as the loop timer (its
//! periods counted against SysTick time), TIM3 PWM outputs (compare values
//! read back), and the DWT cycle counter (which QEMU does not model).
//! `tests/tests/qemu.rs` checks the printed lines.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;
    use cortex_m_semihosting::hprintln;
    use fc_stm32f405::{APB1_TIMER_CLK_HZ, SYSCLK_HZ};
    use hal_shim::stm32f405::{DwtClock, LoopTimer, PwmActuators, SysTickClock};
    use hal_shim::{ActuatorOutput, CycleClock};

    #[entry]
    fn main() -> ! {
        let clock = SysTickClock::start(SYSCLK_HZ);
        // Loop timer at 1 kHz: count its periods over 20 ms of SysTick time.
        let mut timer = LoopTimer::start(APB1_TIMER_CLK_HZ, 1000);
        let t0 = clock.ticks();
        let mut periods = 0u32;
        while clock.ticks() - t0 < u64::from(SYSCLK_HZ / 50) {
            if timer.expired() {
                periods += 1;
            }
        }
        hprintln!("drivers: loop timer 1000 Hz: {} periods in 20 ms", periods);
        let (psc, arr) = timer.registers();
        hprintln!("drivers: loop timer psc {} arr {}", psc, arr);
        // PWM: duty = U / 10 per channel, clamped; read the compare registers back.
        let mut pwm = PwmActuators::start(APB1_TIMER_CLK_HZ, 400, |u| {
            [u[0] / 10.0, u[1] / 10.0, u[2] / 10.0, u[3] / 10.0]
        });
        pwm.apply([5.0, 2.5, 20.0, f32::NAN]);
        let (arr, c) = pwm.registers();
        hprintln!("drivers: pwm arr {} ccr {} {} {} {}", arr, c[0], c[1], c[2], c[3]);
        pwm.disarm();
        let (_, c) = pwm.registers();
        hprintln!("drivers: pwm disarmed ccr {} {} {} {}", c[0], c[1], c[2], c[3]);
        let dwt = DwtClock::start(SYSCLK_HZ);
        let a = dwt.now();
        cortex_m::asm::delay(1000);
        hprintln!(
            "drivers: dwt cyccnt advanced {} (QEMU does not model DWT)",
            dwt.since(a)
        );
        fc_stm32f405::harness_exit(true)
    }

    fc_stm32f405::harness_runtime!("drivers");
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!(
        "drivers runs on the MCU: cargo run --release -p fc-stm32f405 --bin drivers --target thumbv7em-none-eabihf"
    );
}
