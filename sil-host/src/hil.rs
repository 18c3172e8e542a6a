//! The flight-controller core behind PX4's simulator interface, in this
//! process: a TCP client of a simulator that listens on port 4560 (PX4
//! SITL's convention: jMAVSim, Gazebo's bridge, rotorpy's
//! `PX4Multirotor`). Per `HIL_SENSOR` one estimator step (the controller on
//! its schedule), answered by one `HIL_ACTUATOR_CONTROLS` in lockstep;
//! `HIL_STATE_QUATERNION`'s position and heading are the position fix (a
//! mocap-like source every `HIL_FIX_MS`). The flight controller is
//! [`fc_mavlink::vehicle::MavVehicle`], the same code the image runs.
//!
//! Who flies it: either the mission given here, which this process sends
//! into the vehicle as a ground station would (`COMMAND_LONG` arm until
//! accepted — refused while the estimator aligns —, then a
//! `SET_POSITION_TARGET_LOCAL_NED` every step), or an external ground
//! station over UDP ([`HilConfig::gcs`]: telemetry is sent to it, its
//! commands and parameter writes are read from it), as PX4 SITL talks to
//! QGroundControl on port 14550.

use anyhow::{bail, Context, Result};
use fc_core::control::Setpoint;
use fc_mavlink::params::Settings;
use fc_mavlink::vehicle::{MavSink, MavVehicle, Peer};
use fc_mavlink::{common, encode, MavHeader, MavMessage, MavReader, MAX_FRAME};
use nalgebra::Vector3;
use serde::Serialize;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::time::{Duration, Instant};

/// This flight controller's MAVLink system and component ids.
pub const SYSTEM_ID: u8 = 1;
/// Its component id (MAV_COMP_ID_AUTOPILOT1).
pub const COMPONENT_ID: u8 = 1;
/// The system id of the ground station this process plays for a mission.
pub const MISSION_GCS_ID: u8 = 255;

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
    /// The parameters the vehicle boots with (vehicle, motors, controller, failsafe).
    pub settings: Settings,
    /// What to fly; `None`: whatever the ground station commands.
    pub mission: Option<Mission>,
    /// A ground station's UDP address (`127.0.0.1:14550`): telemetry goes
    /// there, its messages are read from the same socket.
    pub gcs: Option<SocketAddr>,
    /// Stop after this much simulated time, s.
    pub duration_s: f64,
}

/// What a HIL flight did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct HilResult {
    /// `HIL_SENSOR` steps answered.
    pub steps: u64,
    /// Simulated time flown, s.
    pub duration_s: f64,
    /// When the vehicle armed, s.
    pub armed_at_s: Option<f64>,
    /// The last position the simulator reported (NED about home, m).
    pub final_pos_ned_m: [f64; 3],
    /// Its distance from the last set-point, m.
    pub final_error_m: f64,
    /// RMS distance from the reference while tracking a scenario, m (3-D).
    pub tracking_rmse_m: Option<f64>,
    /// Largest distance between the estimate and the reported position, m.
    pub max_estimate_error_m: f64,
    /// Steps on which the mixer clamped a motor (armed).
    pub clamped_steps: u64,
    /// MAVLink frames the readers refused (every kind).
    pub refused_frames: u32,
    /// `HIL_SENSOR`s refused (no inertial data, NaN).
    pub refused_sensors: u64,
    /// The vehicle's `STATUSTEXT`s, in order.
    pub status_texts: Vec<String>,
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

/// The vehicle's two links: the simulator's TCP stream and, if any, the
/// ground station's UDP socket. Ground-station messages without a ground
/// station are dropped, except the status texts, which are kept.
struct Links {
    sim: TcpStream,
    gcs: Option<(UdpSocket, SocketAddr)>,
    seq: u8,
    texts: Vec<String>,
}

impl MavSink for Links {
    type Error = anyhow::Error;
    fn send(&mut self, to: Peer, msg: &MavMessage) -> Result<()> {
        if let MavMessage::STATUSTEXT(t) = msg {
            let len = t.text.iter().position(|&b| b == 0).unwrap_or(t.text.len());
            self.texts.push(String::from_utf8_lossy(&t.text[..len]).into_owned());
        }
        let header = MavHeader {
            system_id: u32::from(SYSTEM_ID),
            component_id: COMPONENT_ID,
            sequence: self.seq,
        };
        self.seq = self.seq.wrapping_add(1);
        let mut out = [0u8; MAX_FRAME];
        let n = encode(header, msg, &mut out).map_err(|e| anyhow::anyhow!("{e}"))?;
        match (to, &self.gcs) {
            (Peer::Simulator, _) => self.sim.write_all(&out[..n]).context("writing to the simulator"),
            (Peer::GroundStation, Some((sock, addr))) => {
                // A ground station that has gone away is not an error of the flight.
                let _ = sock.send_to(&out[..n], addr);
                Ok(())
            }
            (Peer::GroundStation, None) => Ok(()),
        }
    }
}

fn setpoint_at(mission: &[Waypoint], t: f64) -> Setpoint<f32> {
    let w = mission.iter().rev().find(|w| w.at_s <= t).or(mission.first());
    match w {
        Some(w) => Setpoint::hold(Vector3::from(w.pos_ned_m).cast(), w.yaw_rad as f32),
        None => Setpoint::hold(Vector3::zeros(), 0.0),
    }
}

/// `sp` as the message a ground station sends for it (position, velocity,
/// acceleration, yaw, yaw rate; the jerk has no field).
pub fn position_target(sp: &Setpoint<f32>, t_ms: u32) -> MavMessage {
    MavMessage::SET_POSITION_TARGET_LOCAL_NED(common::SET_POSITION_TARGET_LOCAL_NED_DATA {
        time_boot_ms: t_ms,
        x: sp.pos_ned_m[0],
        y: sp.pos_ned_m[1],
        z: sp.pos_ned_m[2],
        vx: sp.vel_ned_mps[0],
        vy: sp.vel_ned_mps[1],
        vz: sp.vel_ned_mps[2],
        afx: sp.acc_ned_mps2[0],
        afy: sp.acc_ned_mps2[1],
        afz: sp.acc_ned_mps2[2],
        yaw: sp.yaw_rad,
        yaw_rate: sp.yaw_rate_radps,
        type_mask: common::PositionTargetTypemask::empty(),
        target_system: SYSTEM_ID,
        target_component: COMPONENT_ID,
        coordinate_frame: common::MavFrame::MAV_FRAME_LOCAL_NED,
    })
}

/// The arming command a ground station sends.
pub fn arm_command(arm: bool) -> MavMessage {
    MavMessage::COMMAND_LONG(common::COMMAND_LONG_DATA {
        param1: if arm { 1.0 } else { 0.0 },
        command: common::MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        target_system: SYSTEM_ID,
        target_component: COMPONENT_ID,
        ..Default::default()
    })
}

/// Flies against the simulator at `cfg.addr` until `cfg.duration_s` of
/// simulated time or until it hangs up.
pub fn run(cfg: &HilConfig) -> Result<HilResult> {
    if matches!(&cfg.mission, Some(Mission::Waypoints(w)) if w.is_empty()) {
        bail!("the mission has no set-point");
    }
    if cfg.mission.is_none() && cfg.gcs.is_none() {
        bail!("nothing would fly the vehicle: give a mission or a ground station");
    }
    let mut v = MavVehicle::new(cfg.settings, SYSTEM_ID)
        .map_err(|e| anyhow::anyhow!("the vehicle's parameters are refused: {e}"))?;
    let (mut sq_sum, mut sq_n) = (0.0, 0usize);
    let stream = connect(&cfg.addr, cfg.connect_timeout_s)?;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let gcs = match cfg.gcs {
        Some(addr) => {
            let sock = UdpSocket::bind("0.0.0.0:0").context("opening the ground station's UDP socket")?;
            sock.set_nonblocking(true)?;
            Some((sock, addr))
        }
        None => None,
    };
    let mut links = Links {
        sim: stream.try_clone()?,
        gcs,
        seq: 0,
        texts: Vec::new(),
    };
    links.send(
        Peer::Simulator,
        &MavMessage::HEARTBEAT(fc_mavlink::hil::heartbeat(false)),
    )?;
    let clock = hal_shim::host::MonotonicClock::default();
    let wall = Instant::now();
    let now_us = || wall.elapsed().as_micros() as u64;
    let mut input = stream;
    let mut sim_reader = MavReader::new(SYSTEM_ID);
    let mut gcs_reader = MavReader::new(SYSTEM_ID);
    let mut res = HilResult::default();
    let (mut t0_us, mut next_arm_s) = (None::<u64>, 0.0);
    let mut buf = [0u8; 4096];
    let mut dgram = [0u8; 2048];
    'flight: loop {
        // The ground station's datagrams first (never blocks).
        if let Some((sock, _)) = &links.gcs {
            let sock = sock.try_clone()?;
            while let Ok(n) = sock.recv(&mut dgram) {
                for &b in &dgram[..n] {
                    if let Some(Ok((_, msg))) = gcs_reader.push(b) {
                        v.handle(&msg, &mut links, &clock, now_us())?;
                    }
                }
            }
        }
        let n = match input.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) => {
                return Err(e).with_context(|| {
                    format!(
                        "reading from the simulator after {} steps (MAVLink reader: {:?})",
                        res.steps,
                        sim_reader.counters()
                    )
                })
            }
        };
        for &b in &buf[..n] {
            let Some(Ok((_, msg))) = sim_reader.push(b) else {
                continue;
            };
            let MavMessage::HIL_SENSOR(m) = &msg else {
                v.handle(&msg, &mut links, &clock, now_us())?;
                continue;
            };
            let t0 = *t0_us.get_or_insert(m.time_usec);
            let t = m.time_usec.saturating_sub(t0) as f64 * 1e-6;
            // The mission, sent as a ground station sends it.
            let mut tracking = false;
            if let Some(mission) = &cfg.mission {
                let (sp, track) = mission.setpoint_at(t);
                tracking = track;
                v.handle(&position_target(&sp, (t * 1e3) as u32), &mut links, &clock, now_us())?;
                if !v.armed() && t >= next_arm_s {
                    v.handle(&arm_command(true), &mut links, &clock, now_us())?;
                    next_arm_s = t + 0.5;
                }
            }
            let was_armed = v.armed();
            v.handle(&msg, &mut links, &clock, now_us())?;
            if v.armed() && !was_armed || (v.armed() && res.armed_at_s.is_none()) {
                res.armed_at_s = Some(t);
            }
            res.steps += 1;
            res.duration_s = t;
            let truth = v.reported_position().unwrap_or_default();
            let sp = v.core().setpoint().pos_ned_m.cast::<f64>();
            if tracking {
                sq_sum += (truth - sp).norm_squared();
                sq_n += 1;
            }
            if let Some(e) = v.core().navigator().estimate() {
                let est = e.pos_ned_m.cast::<f64>();
                if v.armed() {
                    res.max_estimate_error_m = res.max_estimate_error_m.max((est - truth).norm());
                }
                res.trace.push([
                    t, truth[0], truth[1], truth[2], est[0], est[1], est[2], sp[0], sp[1], sp[2],
                ]);
            }
            if t >= cfg.duration_s {
                break 'flight;
            }
        }
        let refused = |c: fc_mavlink::MavCounters| c.bad_crc + c.unknown + c.unsupported + c.malformed + c.other_system;
        v.set_link_errors(refused(sim_reader.counters()) + refused(gcs_reader.counters()));
    }
    let c = v.counters();
    let refused = |c: fc_mavlink::MavCounters| c.bad_crc + c.unknown + c.unsupported + c.malformed + c.other_system;
    res.refused_frames = refused(sim_reader.counters()) + refused(gcs_reader.counters());
    res.refused_sensors = u64::from(c.sensors_refused);
    res.clamped_steps = u64::from(c.clamped_steps);
    res.status_texts = std::mem::take(&mut links.texts);
    let truth = v.reported_position().unwrap_or_default();
    res.final_pos_ned_m = truth.into();
    res.tracking_rmse_m = (sq_n > 0).then(|| (sq_sum / sq_n as f64).sqrt());
    let last = v.core().setpoint().pos_ned_m.cast::<f64>();
    res.final_error_m = (truth - last).norm();
    Ok(res)
}
