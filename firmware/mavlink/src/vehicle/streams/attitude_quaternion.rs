//! `ATTITUDE_QUATERNION` (31), 10 Hz: the estimate's attitude (body FRD →
//! NED, scalar first) and its body rates, rad/s.

use super::Stream;
use crate::vehicle::{boot_ms, MavMessage, MavShared, ATTITUDE_QUATERNION_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 31,
    name: "ATTITUDE_QUATERNION",
    interval_us: 100_000,
    build: MavShared::attitude_quaternion,
};

impl MavShared {
    fn attitude_quaternion(&self, t_us: u64) -> Option<MavMessage> {
        let e = self.lp.navigator().estimate()?;
        Some(MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
            time_boot_ms: boot_ms(t_us),
            q1: e.att[0],
            q2: e.att[1],
            q3: e.att[2],
            q4: e.att[3],
            rollspeed: e.rates_frd_radps[0],
            pitchspeed: e.rates_frd_radps[1],
            yawspeed: e.rates_frd_radps[2],
        }))
    }
}
