//! The Crazyflie 2.1 image (`thumbv7em-none-eabihf`), linked at 0x08004000
//! behind Bitcraze's bootloader; its reset handler points VTOR at its own
//! vector table (cortex-m-rt's `set-vtor`).
//!
//! What it runs today: the flight loop (`fc_loop::FlightCore`) in
//! lockstep on USART1, as the `firmware` image does, and the Crazyflie's
//! motors on TIM2/TIM4: every step's inputs go through the loop's mixer
//! (`MOT_FRAME` 4, the Crazyflie's M1–M4, hubs 46 mm out; the vehicle's
//! parameters as written) and the Crazyflie 2.1's thrust curve to the four
//! compare registers; outside a session, in the failsafe
//! or after a fault they are 0. Not yet wired: the BMI088 and BMP388 on
//! I2C3 (the drivers are in this crate's library), the LEDs, the IWDG and
//! the interrupt priorities of the board's own clock. In QEMU the
//! `boot-shim` binary stands in for the bootloader.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
#[path = "../../../stm32f405/src/board.rs"]
mod board;

#[cfg(target_os = "none")]
mod target {
    use crate::board;
    use cortex_m_rt::entry;
    use fc_crazyflie::motors::{self, MotorOutput, CF21_LEGACY_PROPELLERS};
    use fc_loop::params::{Airframe, Settings};
    use fc_loop::{FcConfig, FlightCore};
    use fc_proto::{Counters, PROTOCOL_VERSION};
    use fc_stm32f405::log_changes;
    use stm32f4::stm32f405 as pac;

    /// Hub distance from the centre, m (Bitcraze's `ARM_LENGTH`).
    const HUB_M: f32 = 0.046;

    /// Battery voltage the duty is computed for until the nRF51's battery
    /// reports are wired: a 1S pack at mid charge, V.
    const V_BAT_NOMINAL: f32 = 3.8;

    #[entry]
    fn main() -> ! {
        let (clock, mut usart) = board::bring_up();
        // SAFETY: the only code that touches these blocks; single core.
        let (rcc, gpioa, gpiob, tim2, tim4) = unsafe {
            (
                &*pac::RCC::ptr(),
                &*pac::GPIOA::ptr(),
                &*pac::GPIOB::ptr(),
                &*pac::TIM2::ptr(),
                &*pac::TIM4::ptr(),
            )
        };
        motors::apply_to(rcc, gpioa, gpiob, tim2, tim4);
        board::on_fault_stop_motors(motors_off_now);
        let vtor = unsafe { (*cortex_m::peripheral::SCB::PTR).vtor.read() };
        defmt::info!("Crazyflie 2.1 image: vector table at {=u32:#010x}", vtor);
        let Some(fc) = flight_core() else {
            board::fail("flight loop already taken");
        };
        if fc.start().is_err() {
            board::fail("boot controller design failed");
        }
        let Ok(mut mixer) = fc.settings().mixer() else {
            board::fail("the settings give no mixer");
        };
        let mut designs = fc.selections();
        defmt::info!("up: protocol v{=u16}, waiting on USART1", PROTOCOL_VERSION);
        let mut tx_errors: u32 = 0;
        let mut last = (false, false, Counters::default(), 0u32);
        let (mut saturated, mut saturations) = (false, 0u32);
        loop {
            let now_us = board::now_us(&clock);
            if fc.service(&mut usart, &clock, now_us).is_err() {
                tx_errors = tx_errors.wrapping_add(1);
                defmt::warn!("USART1 transmit timed out ({=u32} so far)", tx_errors);
            }
            // Parameters (the vehicle's, the airframe) change only with a new design.
            if fc.selections() != designs {
                designs = fc.selections();
                if let Ok(m) = fc.settings().mixer() {
                    mixer = m;
                }
            }
            let out = if fc.session_open() && !fc.failsafe() {
                motors::output(
                    &CF21_LEGACY_PROPELLERS,
                    mixer.thrusts(&fc.output()).into(),
                    V_BAT_NOMINAL,
                )
            } else {
                MotorOutput::OFF
            };
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
            motors::set(tim2, tim4, &out);
            log_changes(fc, &mut last);
            board::idle();
        }
    }

    /// The fault handlers' first act on this board: TIM2/TIM4's compares to 0 now.
    fn motors_off_now() -> (&'static str, [u32; 4]) {
        // SAFETY: a fault handler owns the chip from here on.
        let (tim2, tim4) = unsafe { (&*pac::TIM2::ptr(), &*pac::TIM4::ptr()) };
        ("TIM2/TIM4", motors::off_now(tim2, tim4))
    }

    /// The flight loop, in static RAM (see the `firmware` image), with the
    /// Crazyflie's motor order (`MOT_FRAME` 4) and hub distance.
    #[inline(never)]
    fn flight_core() -> Option<&'static mut FlightCore> {
        let settings = Settings {
            airframe: Airframe::XCrazyflie,
            hub_m: HUB_M,
            ..Settings::os4()
        };
        cortex_m::singleton!(: FlightCore = FlightCore::unstarted_with(FcConfig::default(), settings))
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!(
        "firmware-crazyflie: this binary is the Crazyflie 2.1 image; build it with --target thumbv7em-none-eabihf"
    );
}
