//! The telemetry streams, one file a stream as PX4's
//! `mavlink/streams/*.hpp`: each builds its message from the flight stack's
//! state; this table ([`STREAMS`]) says which are sent, keyed by the
//! message's id, at what default rate (`SET_MESSAGE_INTERVAL` changes it).

use super::{autopilot_version, MavMessage, MavShared, MavSink, Peer, AUTOPILOT_VERSION_ID};

mod attitude;
mod attitude_quaternion;
mod estimator_status;
mod extended_sys_state;
mod global_position_int;
mod heartbeat;
mod home_position;
mod local_position_ned;
mod mission_current;
mod sys_status;

/// A telemetry stream (PX4's `MavlinkStream`): its message, its default
/// interval and how its message is built.
#[derive(Debug, Clone, Copy)]
pub struct Stream {
    /// The message's id.
    pub id: u32,
    /// The message's name.
    pub name: &'static str,
    /// The default interval, µs of simulated time
    /// (`MAV_CMD_SET_MESSAGE_INTERVAL` changes it).
    pub interval_us: u64,
    /// The message as of a time, µs; `None` while the vehicle has nothing
    /// it carries (no estimate, no home).
    build: fn(&MavShared, u64) -> Option<MavMessage>,
}

/// The telemetry streams, in the order they are sent when due together.
pub const STREAMS: [Stream; 10] = [
    heartbeat::STREAM,           // 1 Hz (to the simulator too)
    sys_status::STREAM,          // 2 Hz
    attitude::STREAM,            // 50 Hz
    local_position_ned::STREAM,  // 50 Hz
    global_position_int::STREAM, // 10 Hz
    attitude_quaternion::STREAM, // 10 Hz
    extended_sys_state::STREAM,  // 5 Hz
    home_position::STREAM,       // 0.5 Hz
    mission_current::STREAM,     // 1 Hz
    estimator_status::STREAM,    // 2 Hz
];

/// The shortest interval a stream may be set to, µs (the IMU's step).
pub const MIN_INTERVAL_US: u64 = 1_000;

/// Stream messages one step sends at most; the others due wait for the
/// next steps, in [`STREAMS`]' order. Streams whose intervals divide a
/// second all fall due on the same step once a second, and with signing
/// on each message is a SHA-256 in the step's end: ten at once ran that
/// step past the image step's budget on `firmware-mavlink`. Two a step
/// carry the default rates (about 130 messages a second) from a sensor
/// rate of 100 Hz up.
pub const STREAM_MESSAGES_PER_STEP: usize = 2;

impl MavShared {
    /// Sends the telemetry due at simulated time `t_us` ([`STREAMS`], at
    /// their intervals), at most [`STREAM_MESSAGES_PER_STEP`] messages. A
    /// stream sent late keeps its phase (its next time is one interval
    /// after the time it was due), unless it fell a whole interval behind.
    pub(in crate::vehicle) fn telemetry<S: MavSink>(&mut self, t_us: u64, out: &mut S) -> Result<(), S::Error> {
        let mut sent = 0;
        for (k, stream) in STREAMS.iter().enumerate() {
            if sent == STREAM_MESSAGES_PER_STEP {
                break;
            }
            let (interval, next) = self.streams[k];
            if interval == 0 || t_us < next {
                continue;
            }
            let on_phase = next.saturating_add(interval);
            self.streams[k].1 = if on_phase > t_us {
                on_phase
            } else {
                t_us.saturating_add(interval)
            };
            if let Some(m) = (stream.build)(self, t_us) {
                if stream.id == heartbeat::STREAM.id {
                    out.send(Peer::Simulator, &m)?;
                }
                out.send(Peer::GroundStation, &m)?;
                sent += 1;
            }
        }
        Ok(())
    }

    /// Message `id` as of `t_us`, if this vehicle sends it (a stream's, or
    /// `AUTOPILOT_VERSION`) and has what it carries (an estimate, a home).
    pub(in crate::vehicle) fn message(&self, id: u32, t_us: u64) -> Option<MavMessage> {
        if id == AUTOPILOT_VERSION_ID {
            return Some(MavMessage::AUTOPILOT_VERSION(autopilot_version(self.system_id)));
        }
        let stream = STREAMS.iter().find(|s| s.id == id)?;
        (stream.build)(self, t_us)
    }
}
