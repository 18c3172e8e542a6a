//! STM32F405 image of the flight-control core (`thumbv7em-none-eabihf`).
//!
//! For now it boots, builds the hover model in `f32` from the core and reports
//! it over semihosting; the control loop, link and failsafe come with the
//! firmware issue. On the host this file compiles to an empty program so that
//! `cargo build --workspace` works everywhere.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod target {
    use core::panic::PanicInfo;
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};
    use firmware::{euler_hover_model, zoh, VehicleParams};

    #[entry]
    fn main() -> ! {
        let p = VehicleParams::<f32>::os4();
        let lm = euler_hover_model(&p, 0.0f32);
        match zoh(&lm.a, &lm.b, 0.002f32) {
            Ok((ad, bd)) => {
                hprintln!(
                    "firmware: hover model ok, Ad[0][3]={} Bd[5][0]={}",
                    ad[(0, 3)],
                    bd[(5, 0)]
                );
            }
            Err(_) => hprintln!("firmware: discretisation failed"),
        }
        debug::exit(debug::EXIT_SUCCESS);
        loop {
            cortex_m::asm::wfi();
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
