//! A deliberate HardFault on the Crazyflie 2.1 image's layout, for the
//! fault test (`tests/tests/qemu.rs`): booted through the boot shim, the
//! board's handlers (`fc_stm32f405::board`), the Crazyflie's four motors on TIM2/TIM4
//! at about half duty, then an undefined instruction. The handler must
//! zero the four compares (the image's own motors-off, not TIM3's), log
//! over defmt, and end the run as a failure.
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
    use fc_crazyflie::motors::{self, MotorOutput};
    use fc_stm32f405::board;

    #[entry]
    fn main() -> ! {
        let (_clock, _usart) = board::bring_up();
        // SAFETY: the only code that touches the motor peripherals.
        let (tim2, tim4) = unsafe { motors::start_on_chip() };
        board::on_fault_stop_motors(motors::off_now_on_chip);
        let half = MotorOutput {
            compare: [128; 4],
            saturated: false,
        };
        motors::set(tim2, tim4, &half);
        defmt::info!(
            "fault-crazyflie: motors running, compare {}",
            motors::compares(tim2, tim4)
        );
        cortex_m::asm::udf()
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("fault-crazyflie runs on the MCU behind the boot shim (tests/tests/qemu.rs)");
}
