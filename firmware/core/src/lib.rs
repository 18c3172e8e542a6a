//! # fc-core — the quadrotor flight-control core
//!
//! `no_std`, no allocator, no panics on input. Everything here is written once,
//! generic over the float type (`f32` on the STM32F405, `f64` in the host plant),
//! so the simulator and the flight code use the same equations.
//!
//! Conventions (see `docs/book/src/model.md` §1):
//! - earth frame **NED** (z down, altitude = −z), body frame **FRD**;
//! - Euler state `[x y z ẋ ẏ ż φ θ ψ p q r]` (m, m/s, rad, rad/s), ZYX angles;
//! - quaternion state `[x y z ẋ ẏ ż q0 q1 q2 q3 p q r]`, scalar first, body→earth;
//! - inputs `U = [U1 U2 U3 U4]`: thrust (N), roll and pitch forces (N, torques
//!   are `l·U2`, `l·U3`), yaw torque (N·m).
//!
//! Modules:
//! - [`model`]: parameters, mixer, nonlinear dynamics, hover trim, analytic
//!   Jacobians and zero-order-hold discretisation.
//! - [`linalg`]: LU, symmetric eigenvalues, DARE/CARE by doubling.
//! - [`qp`]: the box-constrained QP solver of the MPC.
//! - [`estimate`]: the error-state Kalman filter that turns an IMU and
//!   position fixes into the controllers' state estimate.
//! - [`control`]: PD, LQR and MPC behind [`control::Controller`], chosen by
//!   a [`control::ControllerSpec`].
//! - [`math`]: f32 trigonometry that stays in f32.
//!
//! # Example: design and step each controller family
//!
//! A [`control::ControllerSpec`] names a controller (family, attitude form,
//! preset, reference mode); `build` designs it for a vehicle. Every
//! controller then maps a state estimate and a setpoint to the four inputs.
//!
//! ```
//! use fc_core::control::{Controller, ControllerSpec, Family, Setpoint, StateEstimate};
//! use fc_core::model::{AttitudeForm, VehicleParams};
//! use nalgebra::{Vector3, Vector4};
//!
//! let params = VehicleParams::<f32>::os4(); // the thesis' vehicle
//! // Hold 1 m above the origin (NED: z = −1 m), heading north.
//! let sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0);
//! // The vehicle is 0.5 m below that, level and at rest.
//! let est = StateEstimate {
//!     pos_ned_m: Vector3::new(0.0, 0.0, -0.5),
//!     vel_ned_mps: Vector3::zeros(),
//!     att: Vector4::new(1.0, 0.0, 0.0, 0.0), // scalar first: level, heading north
//!     rates_frd_radps: Vector3::zeros(),
//! };
//! for family in Family::ALL {
//!     let spec = ControllerSpec::new(family, AttitudeForm::Quaternion);
//!     // PD and LQR are designed for a 2 ms step; the MPC presets fix their own.
//!     let mut ctrl = spec.build(params, 0.002)?;
//!     let out = ctrl.update(&est, &sp)?;
//!     // Too low: every controller asks for more than hover thrust, and no
//!     // torque, since nothing but height is off.
//!     assert!(out.u[0] > params.hover_thrust_n(), "{}", spec.name());
//!     assert!(out.u.rows(1, 3).amax() < 1e-3, "{}", spec.name());
//! }
//! # Ok::<(), fc_core::control::ControlError>(())
//! ```
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod control;
pub mod estimate;
pub mod linalg;
pub mod math;
pub mod model;
pub mod qp;

pub use model::*;
