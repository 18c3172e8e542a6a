//! The STM32F405 image speaking CRTP as a Crazyflie 2.1's STM32 does
//! (`thumbv7em-none-eabihf`), linked at 0x0800_0000 for QEMU: the loop of
//! `fc_stm32f405::crtp_image` (syslink to the nRF51 radio on USART6, the
//! vehicle `fc_crtp::vehicle::CrtpVehicle` behind it, the simulator on USART1).
//! Its simulator stands in for the Crazyflie board's BMI088; `firmware-crazyflie`
//! runs the same loop on the Crazyflie's own layout and motors.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
#[path = "../board.rs"]
mod board;

#[cfg(target_os = "none")]
mod target {
    use crate::board;
    use cortex_m_rt::entry;
    use fc_crtp::vehicle::CrtpVehicle;
    use fc_loop::params::Settings;

    #[entry]
    fn main() -> ! {
        let (clock, sim) = board::bring_up();
        let Some(v) = vehicle() else {
            board::fail("vehicle already taken");
        };
        if v.start().is_err() {
            board::fail("boot controller design failed");
        }
        // This board drives no motors of its own: the simulator flies the inputs.
        fc_stm32f405::crtp_image::run(v, sim, clock, board::idle, &mut |_, _| {})
    }

    /// The vehicle, in static RAM (its flight loop and controller are
    /// ≈ 8 KiB), built once and unstarted: the controller is designed in
    /// place by `start`, after this frame is gone. It boots with the OS4's
    /// parameters; the simulator (or a client) writes the vehicle's.
    #[inline(never)]
    fn vehicle() -> Option<&'static mut CrtpVehicle> {
        cortex_m::singleton!(: CrtpVehicle = CrtpVehicle::unstarted(Settings::os4()))
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("firmware-crtp: this binary is the STM32F405 image; build it with --target thumbv7em-none-eabihf");
}
