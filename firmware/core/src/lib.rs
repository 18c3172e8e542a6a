//! # firmware — the quadrotor flight-control core
//!
//! `no_std`, no allocator, no panics on input. Everything here is written once,
//! generic over the float type (`f32` on the STM32F405, `f64` in the host plant),
//! so the simulator and the flight code use the same equations.
//!
//! Conventions (see `docs/model.md` §1):
//! - earth frame **NED** (z down, altitude = −z), body frame **FRD**;
//! - Euler state `[x y z ẋ ẏ ż φ θ ψ p q r]` (m, m/s, rad, rad/s), ZYX angles;
//! - quaternion state `[x y z ẋ ẏ ż q0 q1 q2 q3 p q r]`, scalar first, body→earth;
//! - inputs `U = [U1 U2 U3 U4]`: thrust (N), roll and pitch forces (N, torques
//!   are `l·U2`, `l·U3`), yaw torque (N·m).
//!
//! Modules:
//! - [`model`]: parameters, mixer, nonlinear dynamics, hover trim, analytic
//!   Jacobians and zero-order-hold discretisation.
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod control;
pub mod linalg;
pub mod math;
pub mod model;
pub mod qp;

pub use model::*;
