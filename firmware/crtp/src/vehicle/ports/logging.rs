//! Port log (5): the log TOC ([`LOG_VARS`]) and its blocks, sampled from
//! the telemetry of the flight stack.

use crate::vehicle::*;

/// One log variable: its name, its log type, and how it is read.
#[derive(Debug, Clone, Copy)]
pub struct LogVar {
    /// Group.
    pub group: &'static str,
    /// Name.
    pub name: &'static str,
    /// Log type ([`crate::log::types`]).
    pub kind: u8,
}

macro_rules! vars {
    ($($group:literal . $name:literal : $kind:ident),+ $(,)?) => {
        /// The log TOC, in id order. Positions and velocities are in the
        /// Crazyflie's world frame (x forward, y left, z up; m, m/s),
        /// angles in degrees (roll right-side-down, pitch nose-up and yaw
        /// counter-clockwise positive), `kalman.varP*` the estimator's
        /// position variances (m²), `pm.vbat` volts, `motor.m*` the
        /// commands as fractions of 65 535.
        pub const LOG_VARS: &[LogVar] = &[$(LogVar { group: $group, name: $name, kind: log::types::$kind }),+];
    };
}

vars! {
    "stateEstimate"."x": FLOAT, "stateEstimate"."y": FLOAT, "stateEstimate"."z": FLOAT,
    "stateEstimate"."vx": FLOAT, "stateEstimate"."vy": FLOAT, "stateEstimate"."vz": FLOAT,
    "stateEstimate"."roll": FLOAT, "stateEstimate"."pitch": FLOAT, "stateEstimate"."yaw": FLOAT,
    "stabilizer"."roll": FLOAT, "stabilizer"."pitch": FLOAT, "stabilizer"."yaw": FLOAT,
    "stabilizer"."thrust": FLOAT,
    "kalman"."varPX": FLOAT, "kalman"."varPY": FLOAT, "kalman"."varPZ": FLOAT,
    "pm"."vbat": FLOAT, "pm"."state": I8,
    "motor"."m1": U16, "motor"."m2": U16, "motor"."m3": U16, "motor"."m4": U16,
    "sys"."canfly": U8, "sys"."armed": U8, "supervisor"."info": U16,
    "ctrltarget"."x": FLOAT, "ctrltarget"."y": FLOAT, "ctrltarget"."z": FLOAT,
}

/// A log variable's TOC name.
fn log_name(v: &LogVar) -> Name<'static> {
    Name {
        group: v.group,
        name: v.name,
        lower_group: false,
    }
}

impl CrtpCore {
    /// Samples the log blocks due at the last step's time (their values and
    /// that time, in ms): called once per step, after it is flown
    /// ([`CrtpVehicle::imu_step`]; an image's controller task), so a block's
    /// stamps follow its grid whenever the link sends it.
    pub fn sample_logs(&mut self) {
        if !self.log.any_due(self.now_us) {
            return;
        }
        let values = self.log_values();
        while let Some(p) = self
            .log
            .next_due(self.now_us, |v| values.get(usize::from(v)).copied().unwrap_or(0.0))
        {
            if self.sampled.is_full() {
                self.sampled.pop_front();
            }
            let _ = self.sampled.push_back(p);
        }
    }

    /// The log variables' values now, in [`LOG_VARS`] order.
    pub fn log_values(&self) -> [f32; LOG_VARS.len()] {
        let mut v = [0.0; LOG_VARS.len()];
        let deg = 180.0 / core::f32::consts::PI;
        if let Some(e) = self.core.navigator().estimate() {
            let p = frames::cf_from_ned(&e.pos_ned_m);
            let vel = frames::cf_from_ned(&e.vel_ned_mps);
            let rpy = e.euler();
            let att = [rpy[0] * deg, rpy[1] * deg, frames::heading_from_cf_yaw(rpy[2]) * deg];
            v[0..3].copy_from_slice(&p);
            v[3..6].copy_from_slice(&vel);
            v[6..9].copy_from_slice(&att);
            v[9..12].copy_from_slice(&att);
            let cov = self.core.navigator().estimator().covariance();
            for i in 0..3 {
                v[13 + i] = cov[(i, i)];
            }
        }
        let u1_max = 4.0
            * self.core.vehicle().kf_ns2
            * self.core.vehicle().omega_max_radps
            * self.core.vehicle().omega_max_radps;
        v[12] = (self.u[0] / u1_max).clamp(0.0, 1.0) * 65535.0;
        v[16] = self.battery_v();
        v[17] = f32::from(self.pm_state);
        let motors = self.motors();
        for i in 0..4 {
            v[18 + i] = motors[i].clamp(0.0, 1.0) * 65535.0;
        }
        v[22] = f32::from(u8::from(self.can_fly()));
        v[23] = f32::from(u8::from(self.armed));
        v[24] = f32::from(self.supervisor_bits());
        let target = frames::cf_from_ned(&self.core.setpoint().pos_ned_m);
        v[25..28].copy_from_slice(&target);
        v
    }

    pub(in crate::vehicle) fn on_log<S: CrtpSink>(
        &mut self,
        p: &Packet,
        out: &mut S,
    ) -> Result<Result<(), CrtpError>, S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        match p.channel() {
            0 => match cmd {
                toc::CMD_GET_INFO_V2 => {
                    let crc = toc::crc(LOG_VARS.iter().map(|v| (v.kind, log_name(v))));
                    let extra = [log::MAX_BLOCKS as u8, log::MAX_OPS as u8];
                    if let Ok(r) = toc::info_packet(Port::Log, LOG_VARS.len() as u16, crc, &extra) {
                        out.send(&r)?;
                    }
                }
                toc::CMD_GET_ITEM_V2 => {
                    let Some(id) = u16_at(d, 1) else {
                        return Ok(Err(short(p)));
                    };
                    let r = match LOG_VARS.get(usize::from(id)) {
                        Some(v) => toc::item_packet(Port::Log, id, v.kind, &log_name(v)).unwrap_or(Packet::NULL),
                        None => toc::no_item_packet(Port::Log),
                    };
                    out.send(&r)?;
                }
                _ => return Ok(Err(unsupported(p))),
            },
            1 => {
                let id = d.get(1).copied().unwrap_or(0);
                let vars = LOG_VARS.len() as u16;
                let code = match cmd {
                    2 => self.log.delete(id),
                    3 => match d.get(2) {
                        Some(&tens) => self.log.start(id, u16::from(tens) * 10, self.now_us),
                        None => log::ENOEXEC,
                    },
                    4 => self.log.stop(id),
                    5 => {
                        self.log.reset();
                        0
                    }
                    6 if d.len() >= 2 => self.log.create(id, &d[2..], vars),
                    7 if d.len() >= 2 => self.log.append(id, &d[2..], vars),
                    8 => match u16_at(d, 2) {
                        Some(ms) => self.log.start(id, ms, self.now_us),
                        None => log::ENOEXEC,
                    },
                    _ => log::ENOEXEC,
                };
                if let Ok(r) = log::control_reply(cmd, id, code) {
                    out.send(&r)?;
                }
                if code == log::ENOEXEC {
                    return Ok(Err(unsupported(p)));
                }
            }
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }
}
