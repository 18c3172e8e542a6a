//! The flight-controller core behind PX4's simulator interface, in this
//! process: a TCP client of a simulator that listens on port 4560 (PX4
//! SITL's convention: jMAVSim, Gazebo's bridge, rotorpy's
//! `PX4Multirotor`). Per `HIL_SENSOR` one estimator step (the controller on
//! its schedule), answered by one `HIL_ACTUATOR_CONTROLS` in lockstep;
//! `HIL_STATE_QUATERNION`'s position and heading are the position fix (a
//! mocap-like source at [`HilConfig::fix_period_s`]). The motors stay off
//! (disarmed) until the estimator has aligned at rest, then the vehicle
//! flies the mission's set-points.

use crate::endpoint::{Endpoint, InProcess};
use crate::sensors::Readings;
use anyhow::{bail, Context, Result};
use fc_core::control::{ControllerSpec, Setpoint};
use fc_core::model::airframe::{Mixer, MotorUnit, RotorLayout};
use fc_core::VehicleParams;
use fc_loop::nav::NavMode;
use fc_loop::schedule::{period_us, Schedule};
use fc_mavlink::hil::{self, Home, StateFixSigmas};
use fc_mavlink::{encode, MavHeader, MavMessage, MavReader, MAX_FRAME};
use nalgebra::Vector3;
use serde::Serialize;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// This flight controller's MAVLink system and component ids.
pub const SYSTEM_ID: u8 = 1;
/// Its component id (MAV_COMP_ID_AUTOPILOT1).
pub const COMPONENT_ID: u8 = 1;

/// One set-point of the mission: fly to `pos_ned_m` (about home) with
/// heading `yaw_rad` from `at_s` (simulated time since the first sample).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Waypoint {
    /// From when, s.
    pub at_s: f64,
    /// Where, NED about home, m.
    pub pos_ned_m: [f64; 3],
    /// Heading, rad.
    pub yaw_rad: f64,
}

/// What the vehicle flies once armed.
#[derive(Debug, Clone)]
pub enum Mission {
    /// Set-points to hold, in time order (the first from t = 0).
    Waypoints(Vec<Waypoint>),
    /// Hold the scenario's start until `from_s`, then follow its reference
    /// (position, velocity, acceleration and jerk feed-forward) from its
    /// t = 0; positions NED about home.
    Scenario {
        /// The trajectory.
        scenario: crate::scenario::Scenario,
        /// When it starts, s after the first sample.
        from_s: f64,
    },
}

impl Mission {
    /// The set-point at `t` (s after the first sample), and whether a
    /// trajectory is being tracked (for the RMSE).
    pub fn setpoint_at(&self, t: f64) -> (Setpoint<f32>, bool) {
        match self {
            Mission::Waypoints(w) => (setpoint_at(w, t), false),
            Mission::Scenario { scenario, from_s } => {
                let tracking = t >= *from_s;
                let r = scenario.reference((t - from_s).max(0.0));
                let mut sp = Setpoint::hold(r.pos.cast(), r.yaw as f32);
                if tracking {
                    sp.vel_ned_mps = r.vel.cast();
                    sp.acc_ned_mps2 = r.acc.cast();
                    sp.jerk_ned_mps3 = r.jerk.cast();
                    sp.yaw_rate_radps = r.yaw_rate as f32;
                }
                (sp, tracking)
            }
        }
    }
}

/// Everything a HIL flight needs.
#[derive(Debug, Clone)]
pub struct HilConfig {
    /// The simulator's address (`127.0.0.1:4560`).
    pub addr: String,
    /// How long to keep trying to connect, s.
    pub connect_timeout_s: f64,
    /// The controller.
    pub spec: ControllerSpec,
    /// The vehicle the controller is designed for and the mixer uses.
    pub vehicle: VehicleParams<f64>,
    /// Rotor positions and spins, in the simulator's motor order.
    pub layout: RotorLayout<f32>,
    /// What the simulator reads as a motor command.
    pub unit: MotorUnit,
    /// Period of the fixes taken from `HIL_STATE_QUATERNION`, s.
    pub fix_period_s: f64,
    /// What to fly.
    pub mission: Mission,
    /// Stop after this much simulated time, s.
    pub duration_s: f64,
}

/// What a HIL flight did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct HilResult {
    /// `HIL_SENSOR` steps answered.
    pub steps: u64,
    /// Steps the controller ran at.
    pub control_steps: u64,
    /// Simulated time flown, s.
    pub duration_s: f64,
    /// When the estimator aligned and the motors were armed, s.
    pub armed_at_s: Option<f64>,
    /// The last position the simulator reported (NED about home, m).
    pub final_pos_ned_m: [f64; 3],
    /// Its distance from the last set-point, m.
    pub final_error_m: f64,
    /// RMS distance from the reference while tracking a scenario, m (3-D).
    pub tracking_rmse_m: Option<f64>,
    /// Largest distance between the estimate and the reported position, m.
    pub max_estimate_error_m: f64,
    /// Motor commands clamped by the mixer (steps).
    pub clamped_steps: u64,
    /// MAVLink frames the reader refused (every kind).
    pub refused_frames: u32,
    /// `HIL_SENSOR`s refused (no inertial data, NaN).
    pub refused_sensors: u64,
    /// Rows `[t, north, east, down (reported), north, east, down (estimate), setpoint n, e, d]`.
    #[serde(skip)]
    pub trace: Vec<[f64; 10]>,
}

fn connect(addr: &str, timeout_s: f64) -> Result<TcpStream> {
    let start = Instant::now();
    loop {
        match TcpStream::connect(addr) {
            Ok(s) => return Ok(s),
            Err(e) if start.elapsed().as_secs_f64() > timeout_s => {
                bail!("no simulator listening on {addr} after {timeout_s} s: {e}")
            }
            Err(_) => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}

struct Link {
    stream: TcpStream,
    seq: u8,
}

impl Link {
    fn send(&mut self, msg: &MavMessage) -> Result<()> {
        let header = MavHeader {
            system_id: u32::from(SYSTEM_ID),
            component_id: COMPONENT_ID,
            sequence: self.seq,
        };
        self.seq = self.seq.wrapping_add(1);
        let mut out = [0u8; MAX_FRAME];
        let n = encode(header, msg, &mut out).map_err(|e| anyhow::anyhow!("{e}"))?;
        self.stream.write_all(&out[..n]).context("writing to the simulator")
    }
}

fn setpoint_at(mission: &[Waypoint], t: f64) -> Setpoint<f32> {
    let w = mission.iter().rev().find(|w| w.at_s <= t).or(mission.first());
    match w {
        Some(w) => Setpoint::hold(Vector3::from(w.pos_ned_m).cast(), w.yaw_rad as f32),
        None => Setpoint::hold(Vector3::zeros(), 0.0),
    }
}

/// Flies `cfg` against the simulator at `cfg.addr` until `cfg.duration_s`
/// of simulated time or until it hangs up.
pub fn run(cfg: &HilConfig) -> Result<HilResult> {
    if matches!(&cfg.mission, Mission::Waypoints(w) if w.is_empty()) {
        bail!("the mission has no set-point");
    }
    let (mut sq_sum, mut sq_n) = (0.0, 0usize);
    let vehicle = cfg.vehicle;
    vehicle.check().map_err(|e| anyhow::anyhow!("{e}"))?;
    let mixer = Mixer::new(&cfg.layout, &vehicle.cast::<f32>(), cfg.unit).map_err(|e| anyhow::anyhow!("{e}"))?;
    // PD and LQR at the flight controller's default control period.
    let ts = fc_loop::FcConfig::default().control_period_s;
    let ctrl = cfg
        .spec
        .build_with(vehicle.cast(), ts, None)
        .map_err(|e| anyhow::anyhow!("designing {} failed: {e}", cfg.spec))?;
    let mut ep = InProcess::new(ctrl);
    let ctrl_period = period_us(ep.period_s().unwrap_or(ts));
    let mut schedule = Schedule::new();
    let stream = connect(&cfg.addr, cfg.connect_timeout_s)?;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut link = Link {
        stream: stream.try_clone()?,
        seq: 0,
    };
    let mut input = stream;
    link.send(&MavMessage::HEARTBEAT(hil::heartbeat(false)))?;
    let mut reader = MavReader::new(SYSTEM_ID);
    let mut res = HilResult::default();
    let (mut home, mut t0_us, mut last_fix_us, mut last_beat_us) = (None, None::<u64>, None::<u64>, 0u64);
    let mut fixes = Vec::new();
    let mut truth = Vector3::<f64>::zeros();
    let mut u = nalgebra::Vector4::<f32>::zeros();
    let mut armed = false;
    let mut buf = [0u8; 4096];
    let fix_period_us = period_us(cfg.fix_period_s);
    'flight: loop {
        let n = match input.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) => {
                return Err(e).with_context(|| {
                    format!(
                        "reading from the simulator after {} steps (MAVLink reader: {:?})",
                        res.steps,
                        reader.counters()
                    )
                })
            }
        };
        for &b in &buf[..n] {
            let Some(Ok((_, msg))) = reader.push(b) else { continue };
            match msg {
                MavMessage::HIL_STATE_QUATERNION(m) => {
                    let h = *home.get_or_insert(Home::of(&m));
                    truth = h.ned_m(m.lat, m.lon, m.alt);
                    let due = last_fix_us.is_none_or(|t| m.time_usec >= t + fix_period_us);
                    if due {
                        if let Ok(mut f) = hil::fix_from_hil_state(&m, &h, &StateFixSigmas::MOCAP_LIKE) {
                            // A mocap gives position and heading, not velocity.
                            f.vel_ned_mps = None;
                            fixes.push(f);
                            last_fix_us = Some(m.time_usec);
                        }
                    }
                }
                MavMessage::HIL_SENSOR(m) => {
                    let Ok(s) = hil::imu_from_hil_sensor(&m) else {
                        res.refused_sensors += 1;
                        continue;
                    };
                    let t0 = *t0_us.get_or_insert(s.time_us);
                    let now_us = s.time_us.saturating_sub(t0);
                    let t = now_us as f64 * 1e-6;
                    let control = schedule.due(now_us, ctrl_period);
                    let (sp, tracking) = cfg.mission.setpoint_at(t);
                    let readings = Readings {
                        imu: s.imu,
                        fixes: std::mem::take(&mut fixes),
                    };
                    let step = ep.step_sensed(t, &readings, &sp, &[], control)?;
                    let nav = step.nav.expect("an in-process sensed step reports its estimator");
                    if nav.mode != NavMode::Aligning && !armed {
                        armed = true;
                        res.armed_at_s = Some(t);
                    }
                    if let (true, Some(v)) = (control, step.u) {
                        u = nalgebra::Vector4::from(v);
                        res.control_steps += 1;
                    }
                    let cmd = mixer.commands(&u);
                    res.clamped_steps += u64::from(cmd.clamped && armed);
                    link.send(&MavMessage::HIL_ACTUATOR_CONTROLS(hil::actuator_controls(
                        s.time_us,
                        &cmd.commands,
                        armed,
                    )))?;
                    if now_us >= last_beat_us + 1_000_000 {
                        link.send(&MavMessage::HEARTBEAT(hil::heartbeat(armed)))?;
                        last_beat_us = now_us;
                    }
                    res.steps += 1;
                    res.duration_s = t;
                    if tracking {
                        sq_sum += (truth - sp.pos_ned_m.cast::<f64>()).norm_squared();
                        sq_n += 1;
                    }
                    if let Some(e) = nav.estimate {
                        let est = e.pos_ned_m.cast::<f64>();
                        res.max_estimate_error_m = res.max_estimate_error_m.max((est - truth).norm());
                        let spn = sp.pos_ned_m.cast::<f64>();
                        res.trace.push([
                            t, truth[0], truth[1], truth[2], est[0], est[1], est[2], spn[0], spn[1], spn[2],
                        ]);
                    }
                    if t >= cfg.duration_s {
                        break 'flight;
                    }
                }
                _ => {}
            }
        }
    }
    res.refused_frames = {
        let c = reader.counters();
        c.bad_crc + c.unknown + c.unsupported + c.malformed + c.other_system
    };
    res.final_pos_ned_m = truth.into();
    res.tracking_rmse_m = (sq_n > 0).then(|| (sq_sum / sq_n as f64).sqrt());
    let last = cfg.mission.setpoint_at(res.duration_s).0.pos_ned_m.cast::<f64>();
    res.final_error_m = (truth - last).norm();
    Ok(res)
}
