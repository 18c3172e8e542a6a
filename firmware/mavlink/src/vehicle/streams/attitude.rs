//! `ATTITUDE` (30), 50 Hz: the estimate's roll, pitch and yaw and its body
//! rates (FRD), rad and rad/s.

use super::Stream;
use crate::vehicle::{boot_ms, MavMessage, MavShared, ATTITUDE_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 30,
    name: "ATTITUDE",
    interval_us: 20_000,
    build: MavShared::attitude,
};

impl MavShared {
    fn attitude(&self, t_us: u64) -> Option<MavMessage> {
        let e = self.lp.navigator().estimate()?;
        let rpy = fc_core::quat_to_euler(&e.att);
        Some(MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms: boot_ms(t_us),
            roll: rpy[0],
            pitch: rpy[1],
            yaw: rpy[2],
            rollspeed: e.rates_frd_radps[0],
            pitchspeed: e.rates_frd_radps[1],
            yawspeed: e.rates_frd_radps[2],
        }))
    }
}
