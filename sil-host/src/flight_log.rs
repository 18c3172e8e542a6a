//! Flights written as ULog (PX4's log format, [`crate::ulog`]) as they fly:
//! `sil-host fly --ulog FILE` through [`FlyULog`], a [`RowSink`], and
//! `sil-host px4-hil --ulog FILE` through [`HilULog`]. Topics carry PX4's
//! names; the simulator's truth goes to PX4's ground-truth topics.

use crate::endpoint::NavReport;
use crate::record::RowSink;
use crate::ulog::{px4, Level, ParamValue, Sample, ULogWriter};
use anyhow::Context;
use fc_core::VehicleParams;
use fc_loop::params::{Settings, PARAMS};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// Topic ids, in the order [`TOPICS`] subscribes them.
const POS: usize = 0;
const ATT: usize = 1;
const POS_TRUE: usize = 2;
const ATT_TRUE: usize = 3;
const SETPOINT: usize = 4;
const OUTPUTS: usize = 5;
const STATES: usize = 6;
const STATUS: usize = 7;

/// Every topic a flight log holds.
const TOPICS: [crate::ulog::Format; 8] = [
    px4::VEHICLE_LOCAL_POSITION,
    px4::VEHICLE_ATTITUDE,
    px4::VEHICLE_LOCAL_POSITION_GROUNDTRUTH,
    px4::VEHICLE_ATTITUDE_GROUNDTRUTH,
    px4::VEHICLE_LOCAL_POSITION_SETPOINT,
    px4::ACTUATOR_OUTPUTS,
    px4::ESTIMATOR_STATES,
    px4::VEHICLE_STATUS,
];

/// Simulated seconds → ULog µs.
fn us(t: f64) -> u64 {
    (t.max(0.0) * 1e6).round() as u64
}

/// The parameter table's values in `s`, as ULog parameters (all REAL32, as
/// MAVLink carries them).
fn parameters(s: &Settings) -> Vec<(&'static str, ParamValue)> {
    PARAMS.iter().map(|p| (p.id, ParamValue::Float((p.get)(s)))).collect()
}

fn open(path: &Path, params: &[(&str, ParamValue)]) -> anyhow::Result<ULogWriter<BufWriter<File>>> {
    let f = File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let info = [("sys_name", "fc-core sil-host"), ("ver_sw", env!("CARGO_PKG_VERSION"))];
    ULogWriter::new(BufWriter::new(f), 0, &TOPICS, &info, params).with_context(|| format!("writing {}", path.display()))
}

/// A local position: NED m, m/s, heading rad.
fn local_position(s: &mut Sample, p: [f32; 3], v: [f32; 3], heading: f32) {
    s.f32s(&p)
        .f32s(&v)
        .f32(heading)
        .bool(true)
        .bool(true)
        .bool(true)
        .bool(true);
}

/// Heading (yaw, rad) of a unit quaternion body → NED, scalar first.
fn heading(q: &[f32; 4]) -> f32 {
    let [w, x, y, z] = *q;
    (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z))
}

/// The estimate and its covariance: `vehicle_local_position`,
/// `vehicle_attitude`, `estimator_states`.
fn write_estimate(w: &mut ULogWriter<BufWriter<File>>, t_us: u64, nav: &NavReport) -> anyhow::Result<()> {
    let Some(e) = nav.estimate.as_ref() else {
        return Ok(());
    };
    let q = [e.att[0], e.att[1], e.att[2], e.att[3]];
    let p = [e.pos_ned_m[0], e.pos_ned_m[1], e.pos_ned_m[2]];
    let v = [e.vel_ned_mps[0], e.vel_ned_mps[1], e.vel_ned_mps[2]];
    w.sample(POS, t_us, |s| local_position(s, p, v, heading(&q)))?;
    w.sample(ATT, t_us, |s| {
        s.f32s(&q);
    })?;
    let (bg, ba) = nav.biases;
    let mut states = [0.0f32; 24];
    states[..4].copy_from_slice(&q);
    states[4..7].copy_from_slice(&v);
    states[7..10].copy_from_slice(&p);
    states[10..13].copy_from_slice(bg.as_slice());
    states[13..16].copy_from_slice(ba.as_slice());
    // The error state is [δp δv δθ δb_g δb_a]; PX4 orders attitude, velocity, position, biases.
    let mut cov = [f32::NAN; 24];
    let var = |i: usize| nav.sigmas[i] * nav.sigmas[i];
    for k in 0..3 {
        cov[k] = var(6 + k);
        cov[3 + k] = var(3 + k);
        cov[6 + k] = var(k);
        cov[9 + k] = var(9 + k);
        cov[12 + k] = var(12 + k);
    }
    w.sample(STATES, t_us, |s| {
        s.f32s(&states).u8(16).f32s(&cov);
    })
}

/// `sil-host fly --ulog FILE`: every record row (100 Hz) as the plant's
/// truth (`vehicle_local_position_groundtruth`, `vehicle_attitude_groundtruth`),
/// the reference (`vehicle_local_position_setpoint`; PX4 leaves fields it
/// does not set NaN, so does this) and the motors (`actuator_outputs`,
/// rotor speed ÷ its largest); in a sensor flight, the estimate at the same
/// rate. The flight's parameters (the table, with the flight's vehicle and
/// controller) open the log. Nothing is held: the rows go to the file.
pub struct FlyULog {
    w: ULogWriter<BufWriter<File>>,
    path: PathBuf,
    vehicle: VehicleParams<f64>,
    truth_only: bool,
}

impl FlyULog {
    /// Creates `path` for a flight of `settings` (its vehicle and
    /// controller are the flight's). `truth_only`: no estimator flies, the
    /// controller reads the truth, which is then also the estimate topics'.
    pub fn create(
        path: &Path,
        settings: &Settings,
        vehicle: VehicleParams<f64>,
        truth_only: bool,
    ) -> anyhow::Result<Self> {
        Ok(FlyULog {
            w: open(path, &parameters(settings))?,
            path: path.to_path_buf(),
            vehicle,
            truth_only,
        })
    }

    /// Flushes the file; returns the number of samples written.
    pub fn finish(self) -> anyhow::Result<u64> {
        let n = self.w.samples();
        self.w
            .finish()
            .with_context(|| format!("writing {}", self.path.display()))?;
        Ok(n)
    }

    fn write_row(&mut self, row: &[f64; 21], reference: Option<&[f64; 4]>) -> anyhow::Result<()> {
        let t = us(row[0]);
        let f = |i: usize| row[i] as f32;
        let p = [f(1), f(2), f(3)];
        let v = [f(4), f(5), f(6)];
        let q = [f(7), f(8), f(9), f(10)];
        let yaw = f(13);
        self.w.sample(POS_TRUE, t, |s| local_position(s, p, v, yaw))?;
        self.w.sample(ATT_TRUE, t, |s| {
            s.f32s(&q);
        })?;
        if self.truth_only {
            self.w.sample(POS, t, |s| local_position(s, p, v, yaw))?;
            self.w.sample(ATT, t, |s| {
                s.f32s(&q);
            })?;
        }
        if let Some(r) = reference {
            let nan = f32::NAN;
            self.w.sample(SETPOINT, t, |s| {
                s.f32s(&[r[0] as f32, r[1] as f32, r[2] as f32])
                    .f32s(&[nan; 3])
                    .f32s(&[nan; 3])
                    .f32(r[3] as f32)
                    .f32(nan);
            })?;
        }
        let u = nalgebra::Vector4::new(row[17], row[18], row[19], row[20]);
        let omega = fc_core::model::mixer::rotor_speeds(&self.vehicle, &u);
        let mut out = [0.0f32; 16];
        for (o, w) in out.iter_mut().zip(omega.iter()) {
            *o = (w / self.vehicle.omega_max_radps) as f32;
        }
        self.w.sample(OUTPUTS, t, |s| {
            s.u32(4).f32s(&out);
        })
    }
}

impl RowSink for FlyULog {
    fn push(&mut self, row: &[f64; 21], reference: Option<&[f64; 4]>) -> anyhow::Result<()> {
        let r = self.write_row(row, reference);
        r.with_context(|| format!("writing {}", self.path.display()))
    }

    fn estimate(&mut self, t: f64, nav: &NavReport) -> anyhow::Result<()> {
        write_estimate(&mut self.w, us(t), nav).with_context(|| format!("writing {}", self.path.display()))
    }

    fn log(&mut self, t: f64, text: &str) -> anyhow::Result<()> {
        self.w.log(Level::Info, us(t), text)
    }
}

/// `sil-host px4-hil --ulog FILE`: the simulator's truth at every
/// `HIL_STATE_QUATERNION`, the vehicle's estimate at every
/// `LOCAL_POSITION_NED` / `ATTITUDE_QUATERNION`-equivalent it sends, the
/// mission's set-point, the motor commands of every `HIL_ACTUATOR_CONTROLS`,
/// arming state, `STATUSTEXT`s as logged strings and parameter changes.
pub struct HilULog {
    w: ULogWriter<BufWriter<File>>,
    path: PathBuf,
}

impl HilULog {
    /// Creates `path`; the log opens with `settings`' parameters.
    pub fn create(path: &Path, settings: &Settings) -> anyhow::Result<Self> {
        Ok(HilULog {
            w: open(path, &parameters(settings))?,
            path: path.to_path_buf(),
        })
    }

    fn ctx<T>(&self, r: anyhow::Result<T>) -> anyhow::Result<T> {
        r.with_context(|| format!("writing {}", self.path.display()))
    }

    /// The simulator's position (NED m about home), velocity and attitude.
    pub fn truth(&mut self, t: f64, p: [f32; 3], v: [f32; 3], q: [f32; 4]) -> anyhow::Result<()> {
        let t = us(t);
        let r = self.w.sample(POS_TRUE, t, |s| local_position(s, p, v, heading(&q)));
        self.ctx(r)?;
        let r = self.w.sample(ATT_TRUE, t, |s| {
            s.f32s(&q);
        });
        self.ctx(r)
    }

    /// The vehicle's position estimate (`LOCAL_POSITION_NED`).
    pub fn position(&mut self, t: f64, p: [f32; 3], v: [f32; 3], heading_rad: f32) -> anyhow::Result<()> {
        let r = self.w.sample(POS, us(t), |s| local_position(s, p, v, heading_rad));
        self.ctx(r)
    }

    /// The vehicle's attitude estimate (from `ATTITUDE`'s Euler angles).
    pub fn attitude(&mut self, t: f64, q: [f32; 4]) -> anyhow::Result<()> {
        let r = self.w.sample(ATT, us(t), |s| {
            s.f32s(&q);
        });
        self.ctx(r)
    }

    /// The set-point sent to the vehicle.
    pub fn setpoint(&mut self, t: f64, sp: &fc_core::control::Setpoint<f32>) -> anyhow::Result<()> {
        let r = self.w.sample(SETPOINT, us(t), |s| {
            s.f32s(sp.pos_ned_m.as_slice())
                .f32s(sp.vel_ned_mps.as_slice())
                .f32s(sp.acc_ned_mps2.as_slice())
                .f32(sp.yaw_rad)
                .f32(sp.yaw_rate_radps);
        });
        self.ctx(r)
    }

    /// Motor commands (`HIL_ACTUATOR_CONTROLS.controls`, 0..1).
    pub fn outputs(&mut self, t: f64, controls: &[f32]) -> anyhow::Result<()> {
        let mut out = [0.0f32; 16];
        let n = controls.len().min(16);
        out[..n].copy_from_slice(&controls[..n]);
        let r = self.w.sample(OUTPUTS, us(t), |s| {
            s.u32(4).f32s(&out);
        });
        self.ctx(r)
    }

    /// Armed or not (`HEARTBEAT`), PX4's `arming_state`.
    pub fn status(&mut self, t: f64, armed: bool) -> anyhow::Result<()> {
        let arming = if armed {
            px4::ARMING_STATE_ARMED
        } else {
            px4::ARMING_STATE_STANDBY
        };
        let r = self.w.sample(STATUS, us(t), |s| {
            s.u8(arming).u8(px4::NAV_STATE_OFFBOARD).bool(false);
        });
        self.ctx(r)
    }

    /// A `STATUSTEXT` (its MAVLink severity mapped to the log level).
    pub fn text(&mut self, t: f64, warning: bool, text: &str) -> anyhow::Result<()> {
        let level = if warning { Level::Warning } else { Level::Info };
        let r = self.w.log(level, us(t), text);
        self.ctx(r)
    }

    /// A parameter the vehicle reports (`PARAM_VALUE`) in flight.
    pub fn param(&mut self, name: &str, value: f32) -> anyhow::Result<()> {
        let r = self.w.param(name, ParamValue::Float(value));
        self.ctx(r)
    }

    /// Flushes the file; returns the number of samples written.
    pub fn finish(self) -> anyhow::Result<u64> {
        let n = self.w.samples();
        let path = self.path;
        self.w.finish().with_context(|| format!("writing {}", path.display()))?;
        Ok(n)
    }
}

/// Rows to two sinks (`fly --csv A --ulog B`).
pub struct Tee<'a>(pub &'a mut dyn RowSink, pub &'a mut dyn RowSink);

impl RowSink for Tee<'_> {
    fn push(&mut self, row: &[f64; 21], reference: Option<&[f64; 4]>) -> anyhow::Result<()> {
        self.0.push(row, reference)?;
        self.1.push(row, reference)
    }
    fn estimate(&mut self, t: f64, nav: &NavReport) -> anyhow::Result<()> {
        self.0.estimate(t, nav)?;
        self.1.estimate(t, nav)
    }
    fn log(&mut self, t: f64, text: &str) -> anyhow::Result<()> {
        self.0.log(t, text)?;
        self.1.log(t, text)
    }
}
