//! `LOCAL_POSITION_NED` (32), 50 Hz: the estimate's position and velocity,
//! NED about the origin, m and m/s.

use super::Stream;
use crate::vehicle::{boot_ms, MavMessage, MavShared, LOCAL_POSITION_NED_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 32,
    name: "LOCAL_POSITION_NED",
    interval_us: 20_000,
    build: MavShared::local_position_ned,
};

impl MavShared {
    fn local_position_ned(&self, t_us: u64) -> Option<MavMessage> {
        let e = self.lp.navigator().estimate()?;
        Some(MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
            time_boot_ms: boot_ms(t_us),
            x: e.pos_ned_m[0],
            y: e.pos_ned_m[1],
            z: e.pos_ned_m[2],
            vx: e.vel_ned_mps[0],
            vy: e.vel_ned_mps[1],
            vz: e.vel_ned_mps[2],
        }))
    }
}
