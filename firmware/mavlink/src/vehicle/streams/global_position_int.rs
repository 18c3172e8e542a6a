//! `GLOBAL_POSITION_INT` (33), 10 Hz: the estimate about the simulator's
//! origin as latitude, longitude and altitude, the height above home, the
//! velocity (cm/s) and the heading (cdeg); none before the simulator gave
//! an origin.

use super::Stream;
use crate::vehicle::{boot_ms, MavMessage, MavShared, GLOBAL_POSITION_INT_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 33,
    name: "GLOBAL_POSITION_INT",
    interval_us: 100_000,
    build: MavShared::global_position_int,
};

impl MavShared {
    fn global_position_int(&self, t_us: u64) -> Option<MavMessage> {
        let (e, h) = (self.lp.navigator().estimate()?, self.home?);
        let (lat, lon, alt) = h.geodetic(&e.pos_ned_m.cast());
        let cm = |v: f32| (v * 100.0).clamp(-32_767.0, 32_767.0) as i16;
        let yaw_deg = fc_core::quat_to_euler(&e.att)[2].to_degrees();
        Some(MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
            time_boot_ms: boot_ms(t_us),
            lat,
            lon,
            alt,
            relative_alt: ((self.modes.home_ned_m()[2] - e.pos_ned_m[2]) * 1e3) as i32,
            vx: cm(e.vel_ned_mps[0]),
            vy: cm(e.vel_ned_mps[1]),
            vz: cm(e.vel_ned_mps[2]),
            hdg: (libm::fmodf(yaw_deg + 360.0, 360.0) * 100.0) as u16 % 36_000,
        }))
    }
}
