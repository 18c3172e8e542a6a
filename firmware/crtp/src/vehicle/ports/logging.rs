//! Port log (5): the log TOC ([`LOG_VARS`]) and its blocks, sampled from
//! the telemetry of the flight stack.

use crate::vehicle::*;
use fc_loop::telemetry::Snapshot;

/// What the log variables are read from: the flight stack's snapshot and
/// the CRTP vehicle's own state, taken once per sampling.
#[derive(Debug, Clone, Copy)]
pub struct LogSample {
    /// The flight loop's snapshot.
    pub flight: Snapshot,
    /// The step's inputs `[U1 N, U2 N, U3 N, U4 N·m]`.
    pub u: Vector4<f32>,
    /// The motor commands, fractions of full scale.
    pub motors: [f32; 4],
    /// The battery, V (0 before a reading).
    pub battery_v: f32,
    /// The nRF51's power state (`pm.state`).
    pub pm_state: i8,
    /// The supervisor would let it fly.
    pub can_fly: bool,
    /// Armed.
    pub armed: bool,
    /// The supervisor's state bits.
    pub supervisor: u16,
}

/// One log variable: its name, its log type, and how it is read.
#[derive(Debug, Clone, Copy)]
pub struct LogVar {
    /// Group.
    pub group: &'static str,
    /// Name.
    pub name: &'static str,
    /// Log type ([`crate::log::types`]).
    pub kind: u8,
    /// Its value in a sample.
    pub get: fn(&LogSample) -> f32,
}

const fn var(group: &'static str, name: &'static str, kind: u8, get: fn(&LogSample) -> f32) -> LogVar {
    LogVar { group, name, kind, get }
}

/// Degrees per radian.
const DEG: f32 = 180.0 / core::f32::consts::PI;

/// The Crazyflie's world-frame attitude, degrees: roll, pitch, heading
/// (0 without an estimate).
fn attitude_deg(s: &LogSample) -> [f32; 3] {
    if !s.flight.estimated {
        return [0.0; 3];
    }
    let e = s.flight.euler_rad;
    [e[0] * DEG, e[1] * DEG, frames::heading_from_cf_yaw(e[2]) * DEG]
}

/// An estimated NED vector in the Crazyflie's world frame (0 without an
/// estimate).
fn estimated(s: &LogSample, ned: &Vector3<f32>) -> [f32; 3] {
    if s.flight.estimated {
        frames::cf_from_ned(ned)
    } else {
        [0.0; 3]
    }
}

/// A motor command as the Crazyflie logs it, of 65 535.
fn motor(s: &LogSample, i: usize) -> f32 {
    s.motors[i].clamp(0.0, 1.0) * 65535.0
}

use crate::log::types::{FLOAT, I8, U16, U8};

/// The log TOC, in id order, each variable beside how it is read.
/// Positions and velocities are in the Crazyflie's world frame (x forward,
/// y left, z up; m, m/s), angles in degrees (roll right-side-down, pitch
/// nose-up and yaw counter-clockwise positive), `kalman.varP*` the
/// estimator's position variances (m²), `kalman.state{X,Y,Z}` its position
/// (the same as `stateEstimate.{x,y,z}`, as on a Crazyflie with the Kalman
/// estimator), `pm.vbat` volts, `motor.m*` the
/// commands as fractions of 65 535.
pub const LOG_VARS: &[LogVar] = &[
    var("stateEstimate", "x", FLOAT, |s| estimated(s, &s.flight.pos_ned_m)[0]),
    var("stateEstimate", "y", FLOAT, |s| estimated(s, &s.flight.pos_ned_m)[1]),
    var("stateEstimate", "z", FLOAT, |s| estimated(s, &s.flight.pos_ned_m)[2]),
    var("stateEstimate", "vx", FLOAT, |s| estimated(s, &s.flight.vel_ned_mps)[0]),
    var("stateEstimate", "vy", FLOAT, |s| estimated(s, &s.flight.vel_ned_mps)[1]),
    var("stateEstimate", "vz", FLOAT, |s| estimated(s, &s.flight.vel_ned_mps)[2]),
    var("stateEstimate", "roll", FLOAT, |s| attitude_deg(s)[0]),
    var("stateEstimate", "pitch", FLOAT, |s| attitude_deg(s)[1]),
    var("stateEstimate", "yaw", FLOAT, |s| attitude_deg(s)[2]),
    var("stabilizer", "roll", FLOAT, |s| attitude_deg(s)[0]),
    var("stabilizer", "pitch", FLOAT, |s| attitude_deg(s)[1]),
    var("stabilizer", "yaw", FLOAT, |s| attitude_deg(s)[2]),
    var("stabilizer", "thrust", FLOAT, |s| {
        (s.u[0] / s.flight.u1_max_n).clamp(0.0, 1.0) * 65535.0
    }),
    var("kalman", "varPX", FLOAT, |s| s.flight.pos_var_m2[0]),
    var("kalman", "varPY", FLOAT, |s| s.flight.pos_var_m2[1]),
    var("kalman", "varPZ", FLOAT, |s| s.flight.pos_var_m2[2]),
    var("kalman", "stateX", FLOAT, |s| estimated(s, &s.flight.pos_ned_m)[0]),
    var("kalman", "stateY", FLOAT, |s| estimated(s, &s.flight.pos_ned_m)[1]),
    var("kalman", "stateZ", FLOAT, |s| estimated(s, &s.flight.pos_ned_m)[2]),
    var("pm", "vbat", FLOAT, |s| s.battery_v),
    var("pm", "state", I8, |s| f32::from(s.pm_state)),
    var("motor", "m1", U16, |s| motor(s, 0)),
    var("motor", "m2", U16, |s| motor(s, 1)),
    var("motor", "m3", U16, |s| motor(s, 2)),
    var("motor", "m4", U16, |s| motor(s, 3)),
    var("sys", "canfly", U8, |s| f32::from(u8::from(s.can_fly))),
    var("sys", "armed", U8, |s| f32::from(u8::from(s.armed))),
    var("supervisor", "info", U16, |s| f32::from(s.supervisor)),
    var("ctrltarget", "x", FLOAT, |s| {
        frames::cf_from_ned(&s.flight.setpoint_ned_m)[0]
    }),
    var("ctrltarget", "y", FLOAT, |s| {
        frames::cf_from_ned(&s.flight.setpoint_ned_m)[1]
    }),
    var("ctrltarget", "z", FLOAT, |s| {
        frames::cf_from_ned(&s.flight.setpoint_ned_m)[2]
    }),
];

/// The CRC of the log variables' table of contents as [`toc_item`] serves
/// it ([`toc::crc_of_items`]).
pub(in crate::vehicle) fn toc_crc() -> u32 {
    toc::crc_of_items(LOG_VARS.len() as u16, toc_item)
}

/// The `GET_ITEM_V2` answer for log variable `id`.
fn toc_item(id: u16) -> Packet {
    match LOG_VARS.get(usize::from(id)) {
        Some(v) => toc::item_packet(Port::Log, id, v.kind, &log_name(v)).unwrap_or(Packet::NULL),
        None => toc::no_item_packet(Port::Log),
    }
}

/// A log variable's TOC name.
fn log_name(v: &LogVar) -> Name<'static> {
    Name {
        group: v.group,
        name: v.name,
        lower_group: false,
    }
}

impl CrtpShared {
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

    /// What the log variables are read from now.
    pub fn log_sample(&self) -> LogSample {
        LogSample {
            flight: self.lp.snapshot(),
            u: self.u,
            motors: self.motors(),
            battery_v: self.battery_v(),
            pm_state: self.pm_state,
            can_fly: self.can_fly(),
            armed: self.armed(),
            supervisor: self.supervisor_bits(),
        }
    }

    /// The log variables' values now, in [`LOG_VARS`] order.
    pub fn log_values(&self) -> [f32; LOG_VARS.len()] {
        let sample = self.log_sample();
        let mut v = [0.0; LOG_VARS.len()];
        for (value, var) in v.iter_mut().zip(LOG_VARS) {
            *value = (var.get)(&sample);
        }
        v
    }

    pub(in crate::vehicle) fn on_log<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        match p.channel() {
            0 => match cmd {
                toc::CMD_GET_INFO_V2 => {
                    let extra = [log::MAX_BLOCKS as u8, log::MAX_OPS as u8];
                    if let Ok(r) = toc::info_packet(Port::Log, LOG_VARS.len() as u16, self.toc_crcs.log, &extra) {
                        out.send(&r)?;
                    }
                }
                toc::CMD_GET_ITEM_V2 => {
                    let Some(id) = u16_at(d, 1) else {
                        return Ok(Err(short(p)));
                    };
                    out.send(&toc_item(id))?;
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
