//! Puts this crate's `memory.x` (the STM32F405 memory map) on the linker
//! search path of its binaries as `board-memory.x`, which the workspace's
//! `memory.x` (what cortex-m-rt's `link.x` includes) includes. Only of its own binaries (`rustc-link-arg-bins`, not
//! `rustc-link-search`, which would reach every crate that depends on this
//! one and clash with another board's layout, such as `fc-crazyflie`'s).
//! Host builds ignore it.
use std::{env, fs, path::PathBuf};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let src = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR")).join("memory.x");
    fs::copy(&src, out.join("board-memory.x")).expect("memory.x beside build.rs");
    // `-L` and the directory as two arguments: flip-link (the linker wrapper)
    // reads search paths only in that form.
    println!("cargo:rustc-link-arg-bins=-L");
    println!("cargo:rustc-link-arg-bins={}", out.display());
    println!("cargo:rerun-if-changed={}", src.display());
    println!("cargo:rerun-if-changed=build.rs");
}
