//! A deliberate HardFault, for the fault test (`tests/tests/qemu.rs`): the
//! board's own handlers (`fc_stm32f405::board`, bound as the images bind them), the motors
//! running on TIM3 at half duty, then an undefined instruction. The handler
//! must turn the motors off, log where the fault was over defmt, and end the
//! run as a failure (QEMU exits non-zero).
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
    use cortex_m_rt::entry;
    use fc_stm32f405::board;
    use fc_stm32f405::APB1_TIMER_CLK_HZ;
    use hal_shim::stm32f405::PwmActuators;
    use hal_shim::ActuatorOutput;

    #[entry]
    fn main() -> ! {
        let (_clock, _usart) = board::bring_up();
        // Motors at half duty, as in flight.
        let mut pwm = PwmActuators::start(APB1_TIMER_CLK_HZ, 400, |u| *u);
        pwm.apply([0.5; 4]);
        let (arr, ccr) = pwm.registers();
        defmt::info!("fault: motors running, TIM3 reload {=u32} compare {}", arr, ccr);
        defmt::info!("fault: executing an undefined instruction");
        cortex_m::asm::udf()
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("fault runs on the MCU: cargo run --release -p fc-stm32f405 --bin fault --target thumbv7em-none-eabihf");
}
