//! `HEARTBEAT` (0), 1 Hz, to the ground station and the simulator: PX4's
//! autopilot, armed or not, the mode in PX4's encoding.

use super::Stream;
use crate::hil;
use crate::modes::Px4Mode as _;
use crate::vehicle::{MavMessage, MavShared};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 0,
    name: "HEARTBEAT",
    interval_us: 1_000_000,
    build: MavShared::heartbeat,
};

impl MavShared {
    fn heartbeat(&self, _t_us: u64) -> Option<MavMessage> {
        Some(MavMessage::HEARTBEAT(hil::heartbeat(
            self.modes.armed(),
            self.modes.mode().custom_mode(),
        )))
    }
}
