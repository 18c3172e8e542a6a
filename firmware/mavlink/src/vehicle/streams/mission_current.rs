//! `MISSION_CURRENT` (42), 1 Hz: the mission item flown or next
//! ([`crate::mission::Mission`]).

use super::Stream;
use crate::vehicle::{MavMessage, MavShared};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 42,
    name: "MISSION_CURRENT",
    interval_us: 1_000_000,
    build: MavShared::mission_current,
};

impl MavShared {
    fn mission_current(&self, _t_us: u64) -> Option<MavMessage> {
        Some(self.mission.current_message())
    }
}
