//! The same controller, the same closed loop, on the host and on the MCU:
//! this program flies [`fc_stm32f405::equivalence::run`] in QEMU and prints,
//! per step, `k iterations U1 U2 U3 U4`; `tests/tests/qemu.rs` runs the same
//! function in-process and compares the two. On the host the program prints
//! the same lines (`cargo run -p fc-stm32f405 --bin equivalence`).
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};
    #[entry]
    fn main() -> ! {
        // The FPU's square root (what the core calls on the chip) against
        // libm's (what it calls on the host), bit for bit, over inputs of
        // every exponent, both signs, zeros, infinities and NaN: a
        // difference fails the program before any line is printed.
        let mut bits = 0u32;
        loop {
            let x = f32::from_bits(bits);
            let (chip, host) = (fc_fpu::sqrt(x), libm::sqrtf(x));
            if chip.to_bits() != host.to_bits() && !(chip.is_nan() && host.is_nan()) {
                hprintln!("sqrt({:e}): {:e} on the chip, {:e} in libm", x, chip, host);
                debug::exit(debug::EXIT_FAILURE);
            }
            match bits.checked_add(0x0000_3579) {
                Some(b) => bits = b,
                None => break,
            }
        }
        fc_stm32f405::equivalence::run(|k, it, u| {
            hprintln!("{} {} {:e} {:e} {:e} {:e}", k, it, u[0], u[1], u[2], u[3])
        });
        debug::exit(debug::EXIT_SUCCESS);
        loop {
            cortex_m::asm::wfi();
        }
    }
    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        debug::exit(debug::EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    fc_stm32f405::equivalence::run(|k, it, u| println!("{} {} {:e} {:e} {:e} {:e}", k, it, u[0], u[1], u[2], u[3]));
}
