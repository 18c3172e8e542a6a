//! The Crazyflie 2.1 image (`thumbv7em-none-eabihf`), linked at 0x08004000
//! behind Bitcraze's bootloader; its reset handler points VTOR at its own
//! vector table (cortex-m-rt's `set-vtor`).
//!
//! It is a Crazyflie's STM32 as cflib and cfclient know it: CRTP over
//! syslink to the nRF51 radio on USART6 (`fc_stm32f405::crtp_image`, the
//! loop `firmware-crtp` runs too), the vehicle's parameters and samples from
//! the simulator on USART1, and the Crazyflie's motors on TIM2/TIM4: every
//! step's inputs go through the vehicle's mixer (`MOT_FRAME` 4, the
//! Crazyflie's M1–M4, hubs 46 mm out; the vehicle's parameters as written)
//! and the Crazyflie 2.1's thrust curve at the battery voltage the nRF51
//! reports, to the four compare registers; disarmed, they are 0. A fault
//! zeroes them first. The LEDs show booting, aligning, ready, armed and
//! failsafe (`fc_crazyflie::leds`; QEMU models no GPIO). Not yet wired: the
//! BMI088 and BMP388 on I2C3 (the drivers are in this crate's library), the
//! IWDG and the interrupt priorities of the board's own clock. In QEMU the `boot-shim`
//! binary stands in for the bootloader.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
#[path = "../../../stm32f405/src/board.rs"]
mod board;

#[cfg(target_os = "none")]
mod target {
    use crate::board;
    use cortex_m_rt::entry;
    use fc_crazyflie::leds::{self, pattern, Indication};
    use fc_crazyflie::motors::{self, MotorOutput, CF21_LEGACY_PROPELLERS};
    use fc_crtp::vehicle::CrtpVehicle;
    use fc_loop::nav::NavMode;
    use fc_loop::params::{Airframe, Settings};

    /// Hub distance from the centre, m (Bitcraze's `ARM_LENGTH`).
    const HUB_M: f32 = 0.046;

    /// The fault handlers' first act: the motors off, then the LEDs to "fault".
    fn on_fault() -> (&'static str, [u32; 4]) {
        let stopped = motors::off_now_on_chip();
        // SAFETY: a fault handler is the only code left running.
        let _ = unsafe { leds::start_on_chip() }.show(pattern(Indication::Fault, 0));
        stopped
    }

    #[entry]
    fn main() -> ! {
        let (clock, sim) = board::bring_up();
        // SAFETY: the only code that touches the motor peripherals.
        let (tim2, tim4) = unsafe { motors::start_on_chip() };
        board::on_fault_stop_motors(on_fault);
        // SAFETY: the only code that touches the LED pins.
        let mut leds = unsafe { leds::start_on_chip() };
        let mut last_lit = pattern(Indication::Booting, 0);
        let _ = leds.show(last_lit);
        // SAFETY: a read of SCB.VTOR, which nothing writes after reset.
        let vtor = unsafe { (*cortex_m::peripheral::SCB::PTR).vtor.read() };
        defmt::info!("Crazyflie 2.1 image: vector table at {=u32:#010x}", vtor);
        let Some(v) = vehicle() else {
            board::fail("vehicle already taken");
        };
        if v.start().is_err() {
            board::fail("boot controller design failed");
        }
        let Ok(mut mixer) = v.core().settings().mixer() else {
            board::fail("the settings give no mixer");
        };
        let mut designs = v.core().selections();
        let (mut saturated, mut saturations) = (false, 0u32);
        let (mut armed_steps, mut steps) = (0u32, 0u32);
        let mut drive = |v: &CrtpVehicle, u: &nalgebra::Vector4<f32>| {
            // The vehicle's parameters (and so its mixer) change only with a new design.
            if v.core().selections() != designs {
                designs = v.core().selections();
                if let Ok(m) = v.core().settings().mixer() {
                    mixer = m;
                }
            }
            let out = if v.armed() {
                motors::output(&CF21_LEGACY_PROPELLERS, mixer.thrusts(u).into(), v.battery_v())
            } else {
                MotorOutput::OFF
            };
            motors::set(tim2, tim4, &out);
            // The LEDs, on the steps' clock (1 kHz: `steps` is ms).
            steps = steps.wrapping_add(1);
            let shown = match (v.armed(), v.core().navigator().mode()) {
                (true, NavMode::Failsafe) => Indication::Failsafe,
                (true, _) => Indication::Armed,
                (false, NavMode::Aligning) => Indication::Aligning,
                (false, _) => Indication::Ready,
            };
            // Five pin writes only when what they show changes.
            let lit = pattern(shown, steps);
            if lit != last_lit {
                last_lit = lit;
                let _ = leds.show(lit);
            }
            // Once a second of armed flight (at 1 kHz), what the motors get.
            armed_steps = if v.armed() { armed_steps.wrapping_add(1) } else { 0 };
            if armed_steps % 1000 == 500 {
                defmt::info!("motors: compare {} at {=f32} V", out.compare, v.battery_v());
            }
            if out.saturated != saturated {
                saturated = out.saturated;
                if saturated {
                    saturations = saturations.wrapping_add(1);
                    defmt::warn!(
                        "motors saturated: a rotor needs more than the Crazyflie's thrust curve gives ({=u32} so far)",
                        saturations
                    );
                } else {
                    defmt::info!("motors within the thrust curve again");
                }
            }
        };
        fc_stm32f405::crtp_image::run(v, sim, clock, board::idle, &mut drive)
    }

    /// The vehicle, in static RAM (see `firmware-crtp`), with the
    /// Crazyflie's motor order (`MOT_FRAME` 4) and hub distance; the
    /// simulator (or a client) writes the vehicle's parameters.
    #[inline(never)]
    fn vehicle() -> Option<&'static mut CrtpVehicle> {
        let settings = Settings {
            airframe: Airframe::XCrazyflie,
            hub_m: HUB_M,
            ..Settings::os4()
        };
        cortex_m::singleton!(: CrtpVehicle = CrtpVehicle::unstarted(settings))
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!(
        "firmware-crazyflie: this binary is the Crazyflie 2.1 image; build it with --target thumbv7em-none-eabihf"
    );
}
