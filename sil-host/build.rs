//! Builds the firmware images (`fc-stm32f405`'s `firmware`,
//! `firmware-mavlink` and `firmware-crtp`; `fc-crazyflie`'s
//! `firmware-crazyflie` and `boot-shim`; release, `thumbv7em-none-eabihf`) with cargo, so that `sil-host fly
//! --target qemu` and the report's QEMU table always fly the image of the
//! sources beside them. It goes to its own target directory
//! (`target/firmware-image`) so this nested cargo never waits on the outer
//! one's lock. Their paths reach the crate as `SIL_FIRMWARE_ELF_BUILT`,
//! `SIL_FIRMWARE_MAVLINK_ELF_BUILT`, `SIL_FIRMWARE_CRTP_ELF_BUILT`,
//! `SIL_FIRMWARE_CRAZYFLIE_ELF_BUILT` and `SIL_BOOT_SHIM_ELF_BUILT`; when
//! the build fails (say the thumbv7em target or flip-link is not installed)
//! the host still builds, that variable is empty and
//! `SIL_FIRMWARE_BUILD_ERROR` says why; the script then runs again on every
//! build of the host until the images build, so installing the target
//! (`./test.sh` does) is enough: the README's two commands work in either
//! order.
use std::path::PathBuf;
use std::process::Command;

fn main() {
    let manifest = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let root = manifest.join("..");
    for p in [
        "firmware",
        "hal-shim",
        "memory.x",
        "Cargo.lock",
        "Cargo.toml",
        ".cargo/config.toml",
    ] {
        println!("cargo:rerun-if-changed={}", root.join(p).display());
    }
    println!("cargo:rerun-if-env-changed=SIL_SKIP_FIRMWARE_BUILD");
    let target_dir = root.join("target").join("firmware-image");
    let elf = target_dir.join("thumbv7em-none-eabihf/release/firmware");
    let mavlink_elf = target_dir.join("thumbv7em-none-eabihf/release/firmware-mavlink");
    let crtp_elf = target_dir.join("thumbv7em-none-eabihf/release/firmware-crtp");
    let crazyflie_elf = target_dir.join("thumbv7em-none-eabihf/release/firmware-crazyflie");
    let shim_elf = target_dir.join("thumbv7em-none-eabihf/release/boot-shim");
    let result = if std::env::var_os("SIL_SKIP_FIRMWARE_BUILD").is_some() {
        Err("SIL_SKIP_FIRMWARE_BUILD is set".to_string())
    } else {
        build(&root, &target_dir)
    };
    match result {
        Ok(()) => {
            println!("cargo:rustc-env=SIL_FIRMWARE_ELF_BUILT={}", elf.display());
            println!(
                "cargo:rustc-env=SIL_FIRMWARE_MAVLINK_ELF_BUILT={}",
                mavlink_elf.display()
            );
            println!("cargo:rustc-env=SIL_FIRMWARE_CRTP_ELF_BUILT={}", crtp_elf.display());
            println!(
                "cargo:rustc-env=SIL_FIRMWARE_CRAZYFLIE_ELF_BUILT={}",
                crazyflie_elf.display()
            );
            println!("cargo:rustc-env=SIL_BOOT_SHIM_ELF_BUILT={}", shim_elf.display());
            println!("cargo:rustc-env=SIL_FIRMWARE_BUILD_ERROR=");
        }
        Err(e) => {
            println!("cargo:warning=the firmware image was not built: {e}");
            // A path that does not exist is never fresh: cargo runs this
            // script again on every build until the images build (nothing
            // under firmware/ changes when a target or linker is installed).
            println!("cargo:rerun-if-changed={}", target_dir.join("not-built-yet").display());
            println!("cargo:rustc-env=SIL_FIRMWARE_ELF_BUILT=");
            println!("cargo:rustc-env=SIL_FIRMWARE_MAVLINK_ELF_BUILT=");
            println!("cargo:rustc-env=SIL_FIRMWARE_CRTP_ELF_BUILT=");
            println!("cargo:rustc-env=SIL_FIRMWARE_CRAZYFLIE_ELF_BUILT=");
            println!("cargo:rustc-env=SIL_BOOT_SHIM_ELF_BUILT=");
            println!("cargo:rustc-env=SIL_FIRMWARE_BUILD_ERROR={}", e.replace('\n', " "));
        }
    }
}

fn build(root: &std::path::Path, target_dir: &std::path::Path) -> Result<(), String> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(root)
        .args([
            "build",
            "-q",
            "-p",
            "fc-stm32f405",
            "--bin",
            "firmware",
            "--bin",
            "firmware-mavlink",
            "--bin",
            "firmware-crtp",
            "-p",
            "fc-crazyflie",
            "--bin",
            "firmware-crazyflie",
            "--bin",
            "boot-shim",
        ])
        .arg("--release")
        .args(["--target", "thumbv7em-none-eabihf", "--target-dir"])
        .arg(target_dir)
        // What the outer cargo set for this build script's own compilation
        // must not leak into the image's (its rustflags carry the linker
        // scripts, in .cargo/config.toml).
        .env_remove("CARGO_ENCODED_RUSTFLAGS")
        .env_remove("RUSTFLAGS")
        .env_remove("RUSTC_WORKSPACE_WRAPPER")
        .env_remove("RUSTC_WRAPPER")
        .env_remove("CARGO_TARGET_DIR")
        .env_remove("CARGO_BUILD_TARGET")
        .output()
        .map_err(|e| format!("running cargo: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        let err = String::from_utf8_lossy(&out.stderr);
        let last = err
            .lines()
            .filter(|l| !l.trim().is_empty())
            .take(3)
            .collect::<Vec<_>>()
            .join(" / ");
        Err(format!(
            "cargo build -p fc-stm32f405 -p fc-crazyflie --release --target thumbv7em-none-eabihf failed: {last}"
        ))
    }
}
