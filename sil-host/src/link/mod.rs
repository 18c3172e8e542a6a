//! Flying the core behind the wire protocol: [`client`] (the host end and
//! the [`Remote`] flight endpoint), [`server`] (`sil-host serve`) and
//! [`qemu`] (the firmware image in QEMU). Each depends on the protocol
//! crates, none on another but `qemu` → `client`.

pub mod client;
pub mod qemu;
pub mod server;

pub use client::{FcClient, Remote, RemoteStep, StepInput};
pub use qemu::{
    boot_shim_elf, decode_defmt, firmware_crazyflie_elf, firmware_crtp_elf, firmware_elf, firmware_mavlink_elf,
    qemu_command, qemu_command_booting, Boot, Qemu, SYSTICK_PER_INSTRUCTION,
};
pub use server::{serve, ServeOptions};
