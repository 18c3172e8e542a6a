//! Port localization (6): external position and pose as the estimator's
//! fixes; emergency stop.

use crate::vehicle::*;

/// A position fix from an external position (the Crazyflie's frame, m),
/// `None` unless finite.
fn position_fix(p: [f32; 3]) -> Option<Fix> {
    if !p.iter().all(|v| v.is_finite() && v.abs() <= 1e4) {
        return None;
    }
    let mut f = Fix::EMPTY;
    f.pos_ned_m = Some(frames::ned_from_cf(p));
    f.pos_sigma_m = Vector3::repeat(EXTPOS_SIGMA_M);
    Some(f)
}

impl CrtpShared {
    pub(in crate::vehicle) fn on_localization(&mut self, p: &Packet) -> Result<(), CrtpError> {
        let d = p.payload();
        let bad = CrtpError::BadValue { port: p.port() };
        match (p.channel(), d.first()) {
            (0, _) => {
                let (Some(x), Some(y), Some(z)) = (f32_at(d, 0), f32_at(d, 4), f32_at(d, 8)) else {
                    return Err(short(p));
                };
                let mut fix = position_fix([x, y, z]).ok_or(bad)?;
                if !self.heading_seen && self.lp.navigator().mode() == NavMode::Aligning {
                    fix.yaw_rad = Some(0.0);
                    fix.yaw_sigma_rad = BOOT_HEADING_SIGMA_RAD;
                }
                self.lp.push_fix(&fix);
                Ok(())
            }
            (1, Some(&8)) => {
                let v: [Option<f32>; 7] = core::array::from_fn(|i| f32_at(d, 1 + 4 * i));
                let [Some(x), Some(y), Some(z), Some(qx), Some(qy), Some(qz), Some(qw)] = v else {
                    return Err(short(p));
                };
                let mut fix = position_fix([x, y, z]).ok_or(bad)?;
                let n2 = qx * qx + qy * qy + qz * qz + qw * qw;
                if !(n2.is_finite() && (n2 - 1.0).abs() < 0.1) {
                    return Err(bad);
                }
                fix.yaw_rad = Some(frames::heading_from_cf_yaw(frames::cf_yaw_of_quat(qx, qy, qz, qw)));
                fix.yaw_sigma_rad = EXTPOSE_SIGMA_RAD;
                self.heading_seen = true;
                self.lp.push_fix(&fix);
                Ok(())
            }
            (1, Some(&3)) => {
                self.emergency_stop();
                Ok(())
            }
            (1, Some(&4)) => Ok(()),
            (1, None) => Err(short(p)),
            _ => Err(unsupported(p)),
        }
    }
}
