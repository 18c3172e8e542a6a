//! Port high-level commander (8): take-off, land, go_to and stop, flown as
//! [`crate::planner`] segments; trajectories uploaded into the trajectory
//! memory (port mem, [`super::mem`]) defined and started
//! ([`fc_loop::trajectory`]).

use crate::vehicle::*;
use fc_loop::trajectory::{StartOptions, TrajectoryError};

/// DEFINE_TRAJECTORY's location of a trajectory in the trajectory memory
/// (cflib's `TRAJECTORY_LOCATION_MEM`).
const TRAJECTORY_IN_MEMORY: u8 = 1;
/// DEFINE_TRAJECTORY's type of uncompressed pieces (cflib's
/// `TRAJECTORY_TYPE_POLY4D`; the compressed type, 1, is refused).
const TRAJECTORY_POLY4D: u8 = 0;

impl CrtpShared {
    pub(in crate::vehicle) fn on_high_level(&mut self, p: &Packet) -> Result<(), CrtpError> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Err(short(p));
        };
        let here = self.reference();
        match cmd {
            0 => Ok(()),
            3 => {
                self.client.stop();
                Ok(())
            }
            // TAKEOFF_2 / LAND_2: group, height, yaw, use current yaw, duration.
            7 | 8 => {
                let (Some(h), Some(yaw), Some(&cur), Some(dur)) =
                    (f32_at(d, 2), f32_at(d, 6), d.get(10), f32_at(d, 11))
                else {
                    return Err(short(p));
                };
                let yaw = if cur != 0 {
                    here.yaw_rad
                } else {
                    frames::heading_from_cf_yaw(yaw)
                };
                let goal = Vector3::new(here.pos_ned_m[0], here.pos_ned_m[1], -h);
                self.fly_segment(p, &here, goal, yaw, dur, cmd == 8, false)
            }
            // GO_TO (4): group, relative, x, y, z, yaw, duration; GO_TO_2 (12) adds linear.
            4 | 12 => {
                let at = if cmd == 4 { 3 } else { 4 };
                let vals = [
                    f32_at(d, at),
                    f32_at(d, at + 4),
                    f32_at(d, at + 8),
                    f32_at(d, at + 12),
                    f32_at(d, at + 16),
                ];
                let ([Some(x), Some(y), Some(z), Some(yaw), Some(dur)], Some(&rel)) = (vals, d.get(2)) else {
                    return Err(short(p));
                };
                let linear = cmd == 12 && d.get(3).is_some_and(|&l| l != 0);
                let mut goal = frames::ned_from_cf([x, y, z]);
                let mut heading = frames::heading_from_cf_yaw(yaw);
                if rel != 0 {
                    goal += here.pos_ned_m;
                    heading += here.yaw_rad;
                }
                self.fly_segment(p, &here, goal, heading, dur, false, linear)
            }
            // DEFINE_TRAJECTORY: id, location, type, offset (u32), pieces.
            6 => {
                let (Some(&id), Some(&location), Some(&kind), Some(offset), Some(&pieces)) =
                    (d.get(1), d.get(2), d.get(3), u32_at(d, 4), d.get(8))
                else {
                    return Err(short(p));
                };
                let defined = if (location, kind) != (TRAJECTORY_IN_MEMORY, TRAJECTORY_POLY4D) {
                    Err(TrajectoryError::Kind)
                } else {
                    self.client.define_trajectory(id, offset, pieces)
                };
                defined.map_err(|e| {
                    self.say(format_args!("HL trajectory {id} refused: {e}"));
                    CrtpError::BadValue { port: p.port() }
                })
            }
            // START_TRAJECTORY: group, relative, reversed, id, time scale;
            // START_TRAJECTORY_2 (13) adds relative yaw after relative.
            5 | 13 => {
                let at = if cmd == 5 { 2 } else { 3 };
                let (Some(&relative), Some(&yaw), Some(&reversed), Some(&id), Some(time_scale)) = (
                    d.get(2),
                    if cmd == 5 { Some(&0) } else { d.get(3) },
                    d.get(at + 1),
                    d.get(at + 2),
                    f32_at(d, at + 3),
                ) else {
                    return Err(short(p));
                };
                let options = StartOptions {
                    time_scale,
                    reversed: reversed != 0,
                    relative_position: relative != 0,
                    relative_yaw: yaw != 0,
                };
                if self.start_trajectory(id, options, &here) {
                    Ok(())
                } else {
                    Err(CrtpError::Refused { port: p.port() })
                }
            }
            _ => {
                self.say(format_args!("HL command {cmd}: unsupported"));
                Err(unsupported(p))
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    pub(in crate::vehicle) fn fly_segment(
        &mut self,
        p: &Packet,
        from: &Reference,
        goal: Vector3<f32>,
        yaw: f32,
        dur: f32,
        landing: bool,
        linear: bool,
    ) -> Result<(), CrtpError> {
        let planned = if linear {
            Segment::linear(self.now_us, from, goal, yaw, dur)
        } else {
            Segment::plan(self.now_us, from, goal, yaw, dur)
        };
        let seg = match planned {
            Ok(s) => s,
            Err(e) => {
                self.say(format_args!("HL refused: {e}"));
                return Err(CrtpError::BadValue { port: p.port() });
            }
        };
        if !self.plan(seg, landing) {
            return Err(CrtpError::Refused { port: p.port() });
        }
        Ok(())
    }
}
