//! The STM32F405 images' memory budgets, from their section tables
//! (binutils `size -A`, which comes with gcc): deterministic, so CI
//! enforces them.
//!
//! `firmware` (our protocol):
//! - flash (vector table, code, read-only data, and the initial values of
//!   `.data`, which live in flash too) ≤ 280 KiB: about a quarter of the
//!   F405's 1 MiB, leaving room for a bootloader, parameters and logs. It
//!   was 256 KiB until the parameters came on board (session 10: the table
//!   of 28, their whole-settings checks, the mixer's among them, ≈ 15 KiB;
//!   the image went from 251 340 B to 266 620 B), 272 KiB until the MPC
//!   fitted 1 kHz (issue 14: the exact QP's four block sizes, the
//!   precomputed state responses and the faster products, ≈ 11 KiB; from
//!   273 956 B to 285 060 B), and 280 KiB until the MPC flew at 1 kHz
//!   (issue 29: the per-channel adjoint, unrolled for each channel's size,
//!   the measured-interval observers and the per-block QP certificate,
//!   ≈ 2.5 KiB);
//! - static RAM (`.data`, `.bss`, `.uninit`) ≤ 22 KiB: the flight loop with
//!   its controller (≈ 7.5 KiB, designed in place), the link's queues and
//!   the RTIC tasks' job and answer queues with the previews held for the
//!   controller (≈ 4.3 KiB; 17 KiB before the tasks, 16 KiB until issue 29
//!   added the measured intervals' state).
//!   The stack's high-water mark is the QEMU tests' (≤ 32 KiB for the
//!   budget harness's designs and flights, ≤ 64 KiB for each image with
//!   its tasks nested, `budgets::IMAGE_STACK_BYTES`).
//!
//! `firmware-mavlink` (the same loop behind MAVLink): flash ≤ 392 KiB —
//! the MAVLink messages it reads and writes, the parameter table and the
//! vehicle's logic add ≈ 50 KiB (only the messages used are linked: the
//! whole common dialect would add ≈ 300 KiB); it was 320 KiB until PX4's
//! modes, commands and ground-station telemetry came (seven messages more,
//! the automatic modes' planner and parameters, the mission protocol, the
//! joystick, ESTIMATOR_STATUS: ≈ 30 KiB, 326 228 B to 357 004 B), signing
//! and the settings store ≈ 22 KiB more —, static RAM ≤ 22 KiB (the
//! vehicle's parameters, mixer, modes, mission store of 16 items and
//! telemetry state on top of the loop; 19 484 B with the loop's held
//! previews; 19 KiB until the mission store came; the settings' 2 KiB RAM
//! stand-in since).
//!
//! `firmware-crtp` (the same loop behind CRTP over syslink, the Crazyflie's
//! radio link, on the CRTP images' RTIC tasks): flash ≤ 392 KiB — the CRTP
//! services (TOCs of 72 parameters and 28 log variables, log blocks, the
//! high-level commander's polynomial planner, syslink) and the four tasks
//! add ≈ 77 KiB to the plain image (360 492 B against 283 256 B), the
//! settings store for cflib's persistent parameters ≈ 20 KiB —, static
//! RAM ≤ 36 KiB (the vehicle's log blocks, downlink queue of 16
//! packets and USART6's receive queue on top of the loop, and the tasks'
//! queues: 8 steps or designs for the controller, 2 designs from the link,
//! 8 answers for the simulator; 25 568 B before the settings' 2 KiB RAM
//! stand-in; 28 KiB until the trajectory memory, 4 KiB as the
//! Crazyflie's).

use fc_stm32f405::budgets::*;
use std::process::Command;

const FLASH: std::ops::Range<u64> = 0x0800_0000..0x0810_0000;
const RAM: std::ops::Range<u64> = 0x2000_0000..0x2002_0000;

/// Flash and static RAM of the ELF at `elf`, bytes.
fn footprint(elf: &std::path::Path) -> (u64, u64) {
    let out = Command::new("size")
        .arg("-A")
        .arg(elf)
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
    assert!(flash > 10_000, "an image without code? {flash} B");
    (flash, ram)
}

/// Symbols of core's float formatting (`flt2dec`: Grisu, Dragon4 and
/// their tables, ≈ 17 KiB) in the ELF at `elf`, from its symbol table
/// (binutils `nm`). A float's `Display` or `Debug` anywhere in an image
/// links them; the images print their numbers as integers instead.
fn float_formatting(elf: &std::path::Path) -> Vec<String> {
    let out = Command::new("nm")
        .arg(elf)
        .output()
        .expect("binutils `nm` (installed with gcc)");
    assert!(out.status.success(), "nm failed");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.lines().count() > 100, "unexpected `nm` output:\n{text}");
    text.lines()
        .filter(|l| l.contains("flt2dec"))
        .map(str::to_owned)
        .collect()
}

fn check(name: &str, elf: &std::path::Path, flash_budget: u32, ram_budget: u32) {
    let (flash_budget, ram_budget) = (u64::from(flash_budget), u64::from(ram_budget));
    let floats = float_formatting(elf);
    assert!(floats.is_empty(), "{name} links core's float formatting: {floats:?}");
    let (flash, ram) = footprint(elf);
    eprintln!("{name}: flash {flash} B of {flash_budget}, static RAM {ram} B of {ram_budget}");
    let key = name.replace(' ', "_");
    let src = "image::check";
    e2e_tests::measure(&format!("{key}_flash_bytes"), flash as f64, "B", src);
    e2e_tests::measure(&format!("{key}_static_ram_bytes"), ram as f64, "B", src);
    e2e_tests::measure(
        &format!("{key}_flash_headroom_bytes"),
        flash_budget as f64 - flash as f64,
        "B",
        src,
    );
    assert!(flash <= flash_budget, "{name}: flash {flash} B over {flash_budget} B");
    assert!(ram <= ram_budget, "{name}: static RAM {ram} B over {ram_budget} B");
}

#[test]
fn the_image_fits_its_flash_and_static_ram_budgets() {
    let elf = sil_host::link::firmware_elf().expect("building the thumbv7em image");
    // Static RAM: the flight loop and its controller, the estimator, the
    // USART queue, and the RTIC tasks' job and answer queues (≈ 3 KiB).
    check("image", &elf, FIRMWARE_FLASH_BYTES, FIRMWARE_STATIC_RAM_BYTES);
}

#[test]
fn the_mavlink_image_fits_its_flash_and_static_ram_budgets() {
    let elf = sil_host::link::firmware_mavlink_elf().expect("building the thumbv7em MAVLink image");
    check("mavlink image", &elf, MAVLINK_FLASH_BYTES, MAVLINK_STATIC_RAM_BYTES);
}

#[test]
fn the_crtp_image_fits_its_flash_and_static_ram_budgets() {
    let elf = sil_host::link::firmware_crtp_elf().expect("building the thumbv7em CRTP image");
    check("crtp image", &elf, CRTP_FLASH_BYTES, CRTP_STATIC_RAM_BYTES);
}

/// What the ELF at `elf` loads: each LOAD program header's physical
/// address and size in memory (`readelf -lW`).
fn load_segments(elf: &std::path::Path) -> Vec<(u64, u64)> {
    let out = Command::new("readelf")
        .args(["-lW"])
        .arg(elf)
        .output()
        .expect("binutils `readelf` (installed with gcc)");
    assert!(out.status.success(), "readelf -lW failed");
    let hex = |s: &str| u64::from_str_radix(s.trim_start_matches("0x"), 16).expect("hex");
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter(|l| l.trim_start().starts_with("LOAD"))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            // LOAD offset vaddr paddr filesz memsz flags align: flash holds
            // what is at its physical address (the .data initialisers too).
            (hex(f[3]), hex(f[4]))
        })
        .filter(|&(_, size)| size > 0)
        .collect()
}

/// The Crazyflie 2.1 image (the CRTP images' RTIC application and the
/// Crazyflie's motors, in the bootloader's layout): flash ≤ 392 KiB and
/// static RAM ≤ 36 KiB, as `firmware-crtp` (the motors, their thrust
/// curve, the fault hook and the LEDs add ≈ 5 KiB of flash); everything it
/// puts in flash is at or above 0x08004000, so flashing it (`cfloader`, `dfu-util -s 0x08004000`)
/// leaves Bitcraze's bootloader in sector 0 untouched, and its vector table
/// is the first thing there. The boot shim (QEMU's stand-in for that
/// bootloader) fits the 16 KiB sector.
#[test]
fn the_crazyflie_image_fits_its_budgets_and_leaves_the_bootloader_sector_alone() {
    let elf = sil_host::link::firmware_crazyflie_elf().expect("building the Crazyflie image");
    check(
        "crazyflie image",
        &elf,
        CRAZYFLIE_FLASH_BYTES,
        CRAZYFLIE_STATIC_RAM_BYTES,
    );
    let flash: Vec<(u64, u64)> = load_segments(&elf)
        .into_iter()
        .filter(|(a, _)| FLASH.contains(a))
        .collect();
    assert!(!flash.is_empty());
    for (addr, size) in &flash {
        assert!(
            *addr >= 0x0800_4000,
            "a segment at {addr:#x} ({size} B) would overwrite the bootloader"
        );
    }
    assert_eq!(flash.iter().map(|s| s.0).min(), Some(0x0800_4000), "{flash:x?}");
    let shim = sil_host::link::boot_shim_elf().expect("building the boot shim");
    for (addr, size) in load_segments(&shim).into_iter().filter(|(a, _)| FLASH.contains(a)) {
        assert!(addr + size <= 0x0800_4000, "the shim reaches {:#x}", addr + size);
    }
}
