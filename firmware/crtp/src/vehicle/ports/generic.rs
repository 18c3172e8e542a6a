//! Ports generic set-points (7) and the legacy commander (3).

use crate::vehicle::*;

/// The generic set-points' types (the firmware's
/// `crtp_commander_generic.c`, cflib's `commander.py` `TYPE_*`): the
/// packet's first byte on channel 0.
pub mod setpoint_type {
    /// Stop: motors off.
    pub const STOP: u8 = 0;
    /// Position: x, y, z (m), yaw (deg).
    pub const POSITION: u8 = 7;
    /// Velocity in the world: vx, vy, vz (m/s), yaw rate (deg/s).
    pub const VELOCITY_WORLD: u8 = 8;
    /// Hover: body vx, vy (m/s), yaw rate (deg/s), height (m).
    pub const HOVER: u8 = 10;
    /// On the meta channel (1): notify set-point stop.
    pub const META_NOTIFY_STOP: u8 = 0;
}
use setpoint_type::*;

impl CrtpShared {
    pub(in crate::vehicle) fn on_generic(&mut self, p: &Packet) -> Result<(), CrtpError> {
        let d = p.payload();
        let Some(&kind) = d.first() else {
            return Err(short(p));
        };
        if p.channel() == 1 {
            // Meta: notify set-point stop, valid for a further u32 ms.
            return match (kind, d.get(1..5)) {
                (META_NOTIFY_STOP, Some(ms)) => {
                    let ms = u32::from_le_bytes([ms[0], ms[1], ms[2], ms[3]]);
                    self.client.notify_stop(self.now_us, ms);
                    Ok(())
                }
                (META_NOTIFY_STOP, None) => Err(short(p)),
                _ => Err(unsupported(p)),
            };
        }
        if p.channel() != 0 {
            return Err(unsupported(p));
        }
        if kind == STOP {
            self.client.stop();
            return Ok(());
        }
        let vals = [f32_at(d, 1), f32_at(d, 5), f32_at(d, 9), f32_at(d, 13)];
        let [Some(a), Some(b), Some(c), Some(e)] = vals else {
            return if matches!(kind, POSITION | VELOCITY_WORLD | HOVER) {
                Err(short(p))
            } else {
                Err(unsupported(p))
            };
        };
        if ![a, b, c, e].iter().all(|v| v.is_finite()) {
            return Err(CrtpError::BadValue { port: p.port() });
        }
        let here = self.reference();
        let deg = core::f32::consts::PI / 180.0;
        let mut sp = match self.client.commander().streamed() {
            Some(sp) => *sp,
            None => Setpoint::hold(here.pos_ned_m, here.yaw_rad),
        };
        let mut frame = StreamVelocity::Ned;
        match kind {
            // Position: x, y, z (m), yaw (deg).
            POSITION => {
                sp = Setpoint::hold(frames::ned_from_cf([a, b, c]), frames::heading_from_cf_yaw(e * deg));
            }
            // Velocity in the world: vx, vy, vz (m/s), yaw rate (deg/s).
            VELOCITY_WORLD => {
                sp.vel_ned_mps = frames::ned_from_cf([a, b, c]);
                sp.acc_ned_mps2 = Vector3::zeros();
                sp.yaw_rate_radps = -e * deg;
            }
            // Hover: vx, vy in the body frame (m/s; x forward, y left), yaw
            // rate (deg/s), height (m). The commander turns the velocity
            // with the heading at every step.
            HOVER => {
                frame = StreamVelocity::Heading {
                    forward_mps: a,
                    right_mps: -b,
                };
                sp.vel_ned_mps[2] = 0.0;
                sp.acc_ned_mps2 = Vector3::zeros();
                sp.pos_ned_m[2] = -e;
                sp.yaw_rate_radps = -c * deg;
            }
            _ => return Err(unsupported(p)),
        }
        if !self.stream(sp, frame) {
            return Err(CrtpError::Refused { port: p.port() });
        }
        Ok(())
    }

    pub(in crate::vehicle) fn on_legacy_commander(&mut self, p: &Packet) -> Result<(), CrtpError> {
        // roll, pitch, yaw rate (f32 each), thrust (u16).
        match u16_at(p.payload(), 12) {
            Some(0) => {
                self.client.stop();
                Ok(())
            }
            Some(_) => Err(unsupported(p)),
            None => Err(short(p)),
        }
    }
}
