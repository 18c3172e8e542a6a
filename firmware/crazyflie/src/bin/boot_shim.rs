//! QEMU's stand-in for the Crazyflie bootloader: it occupies the 16 KiB of
//! flash sector 0 (0x08000000) and, as Bitcraze's bootloader does when it
//! is not asked to stay in bootloader mode, loads the stack pointer from
//! 0x08004000 and jumps to the reset vector at 0x08004004. The image sets
//! VTOR itself. On the board the real bootloader is there instead; this
//! program is never flashed.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;

    /// Where the application's vector table starts (flash sector 1).
    const APP: u32 = 0x0800_4000;

    #[entry]
    fn main() -> ! {
        // SAFETY: the image's vector table is at APP (its link address); the
        // shim holds nothing that must survive the jump.
        unsafe { cortex_m::asm::bootload(APP as *const u32) }
    }

    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("boot-shim: QEMU's stand-in for the Crazyflie bootloader; build it with --target thumbv7em-none-eabihf");
}
