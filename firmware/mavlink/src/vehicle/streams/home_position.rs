//! `HOME_POSITION` (242), 0.5 Hz and on request: where the vehicle armed,
//! NED about the origin and as latitude, longitude and altitude; none
//! before the simulator gave an origin.

use super::Stream;
use crate::vehicle::{MavMessage, MavShared, HOME_POSITION_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 242,
    name: "HOME_POSITION",
    interval_us: 2_000_000,
    build: MavShared::home_position,
};

impl MavShared {
    fn home_position(&self, _t_us: u64) -> Option<MavMessage> {
        let h = self.home?;
        let home = self.modes.home_ned_m();
        let (latitude, longitude, altitude) = h.geodetic(&home.cast());
        Some(MavMessage::HOME_POSITION(HOME_POSITION_DATA {
            latitude,
            longitude,
            altitude,
            x: home[0],
            y: home[1],
            z: home[2],
            q: [1.0, 0.0, 0.0, 0.0],
            approach_x: 0.0,
            approach_y: 0.0,
            approach_z: 0.0,
        }))
    }
}
