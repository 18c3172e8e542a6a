//! The STM32F405 image's memory budget, from its section table (binutils
//! `size -A`, which comes with gcc): deterministic, so CI enforces it.
//!
//! - flash (vector table, code, read-only data, and the initial values of
//!   `.data`, which live in flash too) ≤ 256 KiB: a quarter of the F405's
//!   1 MiB, leaving room for a bootloader, parameters and logs;
//! - static RAM (`.data`, `.bss`, `.uninit`) ≤ 16 KiB: the flight loop with
//!   its controller (≈ 7.5 KiB, designed in place) and the link's queues.
//!   The stack's high-water mark (≤ 32 KiB) is the QEMU budget test's; both
//!   together leave more than half of the 128 KiB SRAM for what comes next.

use std::process::Command;

const FLASH_BUDGET_B: u64 = 256 * 1024;
const STATIC_RAM_BUDGET_B: u64 = 16 * 1024;
const FLASH: std::ops::Range<u64> = 0x0800_0000..0x0810_0000;
const RAM: std::ops::Range<u64> = 0x2000_0000..0x2002_0000;

#[test]
fn the_image_fits_its_flash_and_static_ram_budgets() {
    let elf = sil_host::link::firmware_elf().expect("building the thumbv7em image");
    let out = Command::new("size")
        .arg("-A")
        .arg(&elf)
        .output()
        .expect("binutils `size` (installed with gcc)");
    assert!(out.status.success(), "size -A failed");
    let text = String::from_utf8_lossy(&out.stdout);
    let (mut flash, mut ram) = (0u64, 0u64);
    let mut sections = 0;
    for line in text.lines() {
        let f: Vec<&str> = line.split_whitespace().collect();
        let [name, size, addr] = f[..] else { continue };
        let (Ok(size), Ok(addr)) = (size.parse::<u64>(), addr.parse::<u64>()) else {
            continue;
        };
        if FLASH.contains(&addr) {
            flash += size;
        } else if RAM.contains(&addr) {
            ram += size;
            if name == ".data" {
                flash += size; // its initial values are copied from flash at reset
            }
        } else {
            continue;
        }
        sections += 1;
    }
    assert!(sections >= 4, "unexpected `size -A` output:\n{text}");
    eprintln!("image: flash {flash} B of {FLASH_BUDGET_B}, static RAM {ram} B of {STATIC_RAM_BUDGET_B}");
    assert!(flash > 10_000, "an image without code? {flash} B");
    assert!(flash <= FLASH_BUDGET_B, "flash {flash} B over {FLASH_BUDGET_B} B");
    assert!(
        ram <= STATIC_RAM_BUDGET_B,
        "static RAM {ram} B over {STATIC_RAM_BUDGET_B} B"
    );
}
