//! # fc-stm32f405 — the STM32F405 flight-controller image
//!
//! The binary `firmware` (`src/main.rs`) is the image: board bring-up, then
//! the flight loop of `fc-loop` on USART1. The harness programs `budget`,
//! `equivalence` and `drivers` (`src/bin/`) run in QEMU. This library holds
//! what they share and what can be checked on the host.
#![cfg_attr(target_os = "none", no_std)]
#![deny(missing_docs)]
