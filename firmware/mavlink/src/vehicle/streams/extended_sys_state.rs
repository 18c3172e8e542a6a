//! `EXTENDED_SYS_STATE` (245), 5 Hz: PX4's landed state (no VTOL).

use super::Stream;
use crate::vehicle::{MavMessage, MavShared, MavVtolState, EXTENDED_SYS_STATE_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 245,
    name: "EXTENDED_SYS_STATE",
    interval_us: 200_000,
    build: MavShared::extended_sys_state,
};

impl MavShared {
    fn extended_sys_state(&self, _t_us: u64) -> Option<MavMessage> {
        Some(MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
            vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
            landed_state: self.landed_state(),
        }))
    }
}
