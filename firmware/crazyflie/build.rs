//! The memory maps of this crate's two binaries, each on its own linker
//! search path as `board-memory.x` (cortex-m-rt's `link.x` includes the
//! workspace's `memory.x`, which includes that):
//!
//! - `firmware-crazyflie`: flash from 0x08004000 (624 KiB), behind the
//!   Crazyflie bootloader's 16 KiB sector 0, as Bitcraze's own image is
//!   linked, so `cfloader` (radio) and `dfu-util -s 0x08004000` flash it
//!   and the bootloader stays; it ends below sectors 9–11, which keep the
//!   settings and their erase journal (`fc_stm32f405::flash::STORAGE`);
//!   (`fault-crazyflie`, the fault test's program, is linked the same way);
//! - `boot-shim`: the 16 KiB at 0x08000000 (QEMU's stand-in for that bootloader).
//!
//! RAM is the STM32F405's 128 KiB in both. Host builds ignore the maps
//! (and are linked without `--nmagic`).
use std::{env, fs, path::PathBuf};

const IMAGE: &str =
    "/* Crazyflie 2.1 (STM32F405RG): sector 0 holds Bitcraze's bootloader, sectors 9-11 the settings. */
MEMORY
{
  FLASH : ORIGIN = 0x08004000, LENGTH = 624K
  RAM   : ORIGIN = 0x20000000, LENGTH = 128K
}
";

const SHIM: &str = "/* The boot shim: the bootloader's sector 0 only. */
MEMORY
{
  FLASH : ORIGIN = 0x08000000, LENGTH = 16K
  RAM   : ORIGIN = 0x20000000, LENGTH = 128K
}
";

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    for (bin, map) in [
        ("firmware-crazyflie", IMAGE),
        ("fault-crazyflie", IMAGE),
        ("boot-shim", SHIM),
    ] {
        let dir = out.join(bin);
        fs::create_dir_all(&dir).expect("OUT_DIR is writable");
        fs::write(dir.join("board-memory.x"), map).expect("OUT_DIR is writable");
        // `-L` and the directory as two arguments: flip-link (the linker
        // wrapper) reads search paths only in that form.
        println!("cargo:rustc-link-arg-bin={bin}=-L");
        println!("cargo:rustc-link-arg-bin={bin}={}", dir.display());
        // No page alignment: otherwise the linker loads the ELF and program
        // headers into the 16 KiB below 0x08004000 (the bootloader's sector),
        // and a flasher or QEMU would write them over the bootloader.
        // (The host's `cc` knows no such flag: host builds leave it out.)
        if env::var("TARGET").is_ok_and(|t| t.starts_with("thumb")) {
            println!("cargo:rustc-link-arg-bin={bin}=--nmagic");
        }
    }
    println!("cargo:rerun-if-changed=build.rs");
}
