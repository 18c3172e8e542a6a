//! The wire protocol between the flight controller and its host (plant,
//! ground station): postcard messages, framed as `COBS(payload ‖ CRC-32C)`
//! followed by a `0x00` delimiter.
//!
//! Lockstep: the host sends [`ToFc::Sensor`] for step k, the flight
//! controller answers [`FromFc::Actuator`] for step k (and telemetry).
//! A session starts with a version handshake ([`ToFc::Hello`] →
//! [`FromFc::HelloAck`]).
//!
//! This crate knows bytes and messages only (no nalgebra, no controllers):
//! the flight loop (`fc-loop`) turns messages into controller calls, and the
//! controller core (`fc-core`) decides what a `Select`'s id means
//! (`ControllerSpec::from_wire`). The format, byte by byte, is in the
//! book, docs/book/src/protocols/wire.md ("The wire format, byte by byte").
//!
//! # Example: frame a message and parse it back
//!
//! ```
//! use fc_proto::{encode, FrameDecoder, FrameError, ToFc, MAX_FRAME, PROTOCOL_VERSION};
//!
//! let mut wire = [0u8; MAX_FRAME];
//! let n = encode(&ToFc::Hello { version: PROTOCOL_VERSION }, &mut wire)?;
//! assert_eq!(wire[n - 1], 0x00); // the delimiter ends the frame, and only it is zero
//! assert!(wire[..n - 1].iter().all(|&b| b != 0));
//!
//! // The receiver feeds bytes as they arrive; a message comes out at the delimiter.
//! let mut rx = FrameDecoder::<MAX_FRAME>::new();
//! let got: Vec<ToFc> = wire[..n].iter().filter_map(|&b| rx.push(b)).collect::<Result<_, _>>()?;
//! assert_eq!(got, [ToFc::Hello { version: PROTOCOL_VERSION }]);
//!
//! // One flipped bit anywhere is caught by the CRC (or COBS) and dropped, never misread.
//! wire[2] ^= 0x10;
//! let bad = wire[..n].iter().find_map(|&b| rx.push::<ToFc>(b));
//! assert!(matches!(bad, Some(Err(FrameError::Crc | FrameError::Cobs | FrameError::Message))));
//! # Ok::<(), FrameError>(())
//! ```
#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod frame;

pub use frame::{encode, FrameDecoder, FrameError, MAX_FRAME};

use serde::{Deserialize, Serialize};

/// Protocol version; both ends must agree in the handshake.
pub const PROTOCOL_VERSION: u16 = 6;

/// A setpoint on the wire: NED position, velocity, acceleration, jerk (SI),
/// heading and heading rate (rad, rad/s).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WireSetpoint {
    /// Position, NED, m.
    pub pos: [f32; 3],
    /// Velocity, NED, m/s.
    pub vel: [f32; 3],
    /// Acceleration, NED, m/s².
    pub acc: [f32; 3],
    /// Jerk, NED, m/s³.
    pub jerk: [f32; 3],
    /// Heading, rad.
    pub yaw: f32,
    /// Heading rate, rad/s.
    pub yaw_rate: f32,
}

/// Host → flight controller.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ToFc {
    /// Start of a session.
    Hello {
        /// The host's [`PROTOCOL_VERSION`].
        version: u16,
    },
    /// Choose the controller (rebuilt on the flight controller).
    Select {
        /// Which one: a wire id of the controller table (`fc_core::control::SPECS`;
        /// 0 PD Euler … 7 MPC thesis quaternion). On the wire the same byte as
        /// protocol v2's enum index (postcard encodes indices below 128 as one byte).
        controller: u8,
        /// Feed the reference forward (`false`: thesis-faithful).
        feedforward: bool,
    },
    /// The setpoint for the coming steps.
    Setpoint(WireSetpoint),
    /// A reference preview point `k` prediction steps ahead (MPC; 1-based).
    Preview {
        /// Step index, 1-based.
        k: u8,
        /// The setpoint there.
        sp: WireSetpoint,
    },
    /// The state for control step `seq`: `[x y z vx vy vz q0 q1 q2 q3 p q r]`
    /// (NED m, m/s; quaternion body→NED; body rad/s). Answered with an actuator
    /// command for the same `seq`.
    Sensor {
        /// Step number, strictly increasing.
        seq: u32,
        /// Time of this sample, µs: in lockstep the flight loop's
        /// clock (it must increase; a frame whose time does not is not
        /// flown and is counted as out of order; since protocol v3).
        t_us: u64,
        /// The quaternion-form state.
        state: [f32; 13],
    },
    /// Liveness.
    Heartbeat {
        /// Echoed back.
        seq: u32,
    },
    /// One IMU sample, body FRD, as step `seq` (since protocol v4): the
    /// flight controller's estimator integrates it over the time since the
    /// previous `Imu` (sent at the IMU's rate, 1 kHz in the SIL); its
    /// controller runs on its own schedule (every 2 ms for PD/LQR, 5 ms for
    /// the fast MPC, on the grid of the first step), and every `Imu` is
    /// answered as a `Sensor` is, plus a `Nav`.
    Imu {
        /// Step number, strictly increasing (shared with `Sensor`).
        seq: u32,
        /// Time of this step, µs (the lockstep clock, as for `Sensor`).
        t_us: u64,
        /// Body rates (p, q, r), rad/s.
        gyro: [f32; 3],
        /// Specific force, m/s² (`(0, 0, −g)` at rest).
        accel: [f32; 3],
    },
    /// A slow-sensor measurement, fused at the next `Imu` step (since
    /// protocol v4). Absent parts are `None`; sigmas are 1σ.
    Fix(WireFix),
    /// Set parameter `index` of the flight controller's table (since
    /// protocol v6; the table is `fc_loop::params::PARAMS`, MAVLink's
    /// names). Answered with a `Param`: the value in force and, if the
    /// write was refused, why. A change of the vehicle or the controller
    /// is accepted only before the session's first `Sensor`/`Imu` step.
    ParamSet {
        /// The parameter's index.
        index: u16,
        /// Its new value (every parameter is an `f32`).
        value: f32,
    },
    /// Read parameter `index` (since protocol v6): answered with a `Param`.
    ParamRead {
        /// The parameter's index.
        index: u16,
    },
}

/// A position/velocity/heading/altitude fix on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct WireFix {
    /// Time from the measurement to the `Imu` step it is fused at, µs.
    pub age_us: u32,
    /// Position, NED, m.
    pub pos: Option<[f32; 3]>,
    /// 1σ per position axis, m.
    pub pos_sigma: [f32; 3],
    /// Velocity, NED, m/s.
    pub vel: Option<[f32; 3]>,
    /// 1σ per velocity axis, m/s.
    pub vel_sigma: f32,
    /// Heading, rad.
    pub yaw: Option<f32>,
    /// 1σ of the heading, rad.
    pub yaw_sigma: f32,
    /// Barometric altitude (up), m.
    pub alt: Option<f32>,
    /// 1σ of the altitude, m.
    pub alt_sigma: f32,
}

/// Error and frame counters the flight controller reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Counters {
    /// Frames accepted.
    pub ok: u32,
    /// Frames whose CRC did not match.
    pub bad_crc: u32,
    /// Frames whose COBS encoding was invalid (or empty).
    pub bad_cobs: u32,
    /// Frames that decoded to no known message.
    pub bad_message: u32,
    /// Frames longer than the receive buffer (dropped up to the next delimiter).
    pub oversized: u32,
    /// Sensor frames whose sequence number did not increase.
    pub out_of_order: u32,
    /// Messages with NaN/∞ or out-of-range values.
    pub invalid_values: u32,
    /// Messages that arrived in a state that does not accept them.
    pub unexpected: u32,
    /// Times the failsafe took over (no valid sensor frame in time). A
    /// failsafe that starts and ends between two sensor frames shows only here.
    pub failsafe_entries: u32,
}

/// Flight controller → host.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FromFc {
    /// Handshake answer.
    HelloAck {
        /// The flight controller's [`PROTOCOL_VERSION`].
        version: u16,
        /// Versions match; the session is open.
        accepted: bool,
    },
    /// Inputs for control step `seq`: `[U1 N, U2 N, U3 N, U4 N·m]`, inside the box.
    Actuator {
        /// The sensor step this answers.
        seq: u32,
        /// The inputs.
        u: [f32; 4],
        /// The failsafe produced them (no controller output).
        failsafe: bool,
    },
    /// What the step cost and how the link is doing.
    Telemetry {
        /// The sensor step this describes.
        seq: u32,
        /// Cycles (instructions under QEMU icount) spent in the controller.
        cycles: u32,
        /// QP iterations (MPC; 0 otherwise).
        qp_iterations: u16,
        /// Frame and error counters.
        counters: Counters,
        /// Failsafe active.
        failsafe: bool,
    },
    /// Liveness answer.
    Heartbeat {
        /// The host's sequence number.
        seq: u32,
    },
    /// The on-board estimate after an `Imu` step (since protocol v4).
    Nav {
        /// The step this describes.
        seq: u32,
        /// 0 aligning (no estimate: the fields are zero), 1 navigating, 2 failsafe.
        mode: u8,
        /// Position, NED, m.
        pos: [f32; 3],
        /// Velocity, NED, m/s.
        vel: [f32; 3],
        /// Attitude, body FRD → NED, scalar first.
        att: [f32; 4],
        /// 1σ of the error state's first nine: position (m), velocity
        /// (m/s), attitude (rad, NED rotation vector).
        sigma: [f32; 9],
        /// IMU samples the estimator refused (NaN/∞, out of range, clipped).
        imu_rejected: u32,
        /// Fix parts the estimator refused (gate, bad values) or dropped
        /// (more arrived than its queue holds).
        fixes_rejected: u32,
        /// Failsafe episodes of the estimator.
        failsafe_entries: u32,
    },
    /// The estimator's sensor biases and their 1σ after an `Imu` step, sent
    /// after its `Nav` (since protocol v5): with `Nav.sigma`, the whole
    /// diagonal of the error-state covariance (it does not fit one frame).
    NavBias {
        /// The step this describes.
        seq: u32,
        /// Gyro bias, body FRD, rad/s.
        gyro_bias: [f32; 3],
        /// Accelerometer bias, body FRD, m/s².
        accel_bias: [f32; 3],
        /// 1σ of the error state's last six: gyro bias (rad/s), accelerometer bias (m/s²).
        sigma: [f32; 6],
    },
    /// A parameter's value in force, the answer to `ParamSet` and
    /// `ParamRead` (since protocol v6).
    Param {
        /// Its index.
        index: u16,
        /// How many parameters there are.
        count: u16,
        /// Its name, NUL-padded (MAVLink's `param_id`); all zero for an unknown index.
        id: [u8; 16],
        /// Its value (NaN for an unknown index).
        value: f32,
        /// 0: read, or written as asked; else why not: 1 no such
        /// parameter, 2 out of range, 3 not a whole number, 4 no such
        /// controller, 5 the motors cannot be mixed, 6 the controller could
        /// not be designed, 7 re-design refused in flight, 8 a re-design
        /// is under way (write again once it is answered).
        refusal: u8,
    },
}
