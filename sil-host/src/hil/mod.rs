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
//! into the vehicle as a ground station would (a
//! `SET_POSITION_TARGET_LOCAL_NED` as the set-point changes, PX4's Offboard
//! mode and arming until accepted — refused while the estimator aligns), or an external ground
//! station over UDP ([`HilConfig::gcs`]: telemetry is sent to it, its
//! commands and parameter writes are read from it), as PX4 SITL talks to
//! QGroundControl on port 14550.

use anyhow::{bail, Context, Result};
use fc_core::control::{Setpoint, StateEstimate};
use fc_mavlink::params::Settings;
use fc_mavlink::signing::Signing;
use fc_mavlink::vehicle::{MavSink, MavVehicle, Peer};
use fc_mavlink::{common, encode, encode_signed, MavHeader, MavMessage, MavReader, MAX_FRAME};
use nalgebra::Vector3;
use serde::Serialize;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, UdpSocket};
use std::time::{Duration, Instant};

mod backends;
pub mod trajectory;

pub use backends::truth_from_odometry;
use backends::{write_parameters, InProcess, InQemu};

/// `ODOMETRY`'s message id: the simulator's true state (`--state truth`).
const ODOMETRY_ID: u32 = 331;

/// This flight controller's MAVLink system and component ids.
pub const SYSTEM_ID: u8 = 1;
/// Its component id (MAV_COMP_ID_AUTOPILOT1).
pub const COMPONENT_ID: u8 = 1;
/// Shortest interval between two set-points sent for a mission, s (100 Hz).
pub const SETPOINT_PERIOD_S: f64 = 0.01;
/// Longest interval between two set-points of a mission (one that does not
/// change is sent again), s: PX4's Offboard ends after 1 s without one.
pub const SETPOINT_REPEAT_S: f64 = 0.2;
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
    /// Hold the trajectory's hover heading north, then at its start hand
    /// the vehicle the trajectory as if a client had uploaded it
    /// ([`trajectory`]): it flies it on board, its controller previewing
    /// it, and nothing more is streamed. The host evaluates the same pieces
    /// for its trace.
    Trajectory(trajectory::Flown),
}

impl Mission {
    /// The set-point at `t` (s after the first sample), and whether the
    /// tracking error counts (for the RMSE: from the scenario's
    /// [`tracking_from_s`](crate::scenario::Scenario::tracking_from_s) after it starts).
    pub fn setpoint_at(&self, t: f64) -> (Setpoint<f32>, bool) {
        match self {
            Mission::Waypoints(w) => (setpoint_at(w, t), false),
            Mission::Scenario { scenario, from_s } => {
                let moving = t >= *from_s;
                let tracking = t >= *from_s + scenario.tracking_from_s().unwrap_or(0.0);
                let r = scenario.reference((t - from_s).max(0.0));
                let mut sp = Setpoint::hold(r.pos.cast(), r.yaw as f32);
                if moving {
                    sp.vel_ned_mps = r.vel.cast();
                    sp.acc_ned_mps2 = r.acc.cast();
                    sp.jerk_ned_mps3 = r.jerk.cast();
                    sp.yaw_rate_radps = r.yaw_rate as f32;
                }
                (sp, tracking)
            }
            Mission::Trajectory(flown) => {
                let tracking = (flown.from_s..=flown.from_s + f64::from(flown.duration_s)).contains(&t);
                (flown.setpoint_at(t), tracking)
            }
        }
    }

    /// Its headings are the mission's own (north 0), not about the
    /// take-off heading (a trajectory's, as a Crazyflie flies it).
    fn absolute_heading(&self) -> bool {
        matches!(self, Mission::Trajectory(_))
    }
}

/// Where the flight controller runs.
#[derive(Debug, Clone)]
pub enum Target {
    /// In this process ([`MavVehicle`]).
    InProcess,
    /// The `firmware-mavlink` image in QEMU's netduinoplus2, its USART1 on
    /// a local TCP socket (both the simulator's and the ground station's
    /// messages on that one link; this process routes them).
    Qemu(std::path::PathBuf),
}

/// Everything a HIL flight needs.
#[derive(Debug, Clone)]
pub struct HilConfig {
    /// The simulator's address (`127.0.0.1:4560`).
    pub addr: String,
    /// How long to keep trying to connect, s.
    pub connect_timeout_s: f64,
    /// The parameters the vehicle flies with (vehicle, motors, controller,
    /// failsafe): the boot parameters in process; written with PARAM_SET
    /// (and each echo checked) before the flight on the image.
    pub settings: Settings,
    /// What to fly; `None`: whatever the ground station commands.
    pub mission: Option<Mission>,
    /// A ground station's UDP address (`127.0.0.1:14550`): telemetry goes
    /// there, its messages are read from the same socket.
    pub gcs: Option<SocketAddr>,
    /// Stop after this much simulated time, s.
    pub duration_s: f64,
    /// Where the flight controller runs.
    pub target: Target,
    /// Write the flight as a ULog here (PX4's log format), as it flies.
    pub ulog: Option<std::path::PathBuf>,
    /// Keep the vehicle's settings in this file (its flash, in process):
    /// parameters set and the signing key are read at boot and written
    /// when they change; the key's timestamp at the end.
    pub storage: Option<std::path::PathBuf>,
    /// Fly the simulator's true state (its `ODOMETRY`, [`truth_from_odometry`])
    /// in place of the estimate: the controller alone, as a peer given
    /// perfect state flies. In process only.
    pub truth_state: bool,
    /// The controller previews what the commander flies (`false`: it
    /// extrapolates each step's set-point; a measurement of what the
    /// preview is worth, in process only).
    pub exact_preview: bool,
}

/// What `--storage` did.
#[derive(Debug, Clone, Default, Serialize)]
pub struct StorageSummary {
    /// What the store was at boot (the `storage:` line on stderr).
    pub boot: String,
    /// Stored parameter values taken at boot.
    pub params_loaded: u16,
    /// Stored values the parameters' checks refused at boot (defaults kept).
    pub params_refused: u16,
    /// Whether a signing key was read at boot (signing on from the start).
    pub key_loaded: bool,
    /// The signing timestamp read at boot, and the one stored at the end
    /// (10 µs since 2015-01-01; 0: none).
    pub timestamps: [u64; 2],
    /// Why something could not be stored, if it could not.
    pub error: Option<String>,
}

/// What a HIL flight did, measured from the messages that crossed the
/// links (the same for every target).
#[derive(Debug, Clone, Default, Serialize)]
pub struct HilResult {
    /// Where the flight controller ran: `in-process` or `qemu`.
    pub target: String,
    /// `HIL_SENSOR` steps answered.
    pub steps: u64,
    /// Simulated time flown, s.
    pub duration_s: f64,
    /// When the vehicle armed (its `COMMAND_ACK` or `HEARTBEAT`), s.
    pub armed_at_s: Option<f64>,
    /// Its heading estimate then (`ATTITUDE`), rad: the mission's headings
    /// are about it.
    pub takeoff_heading_rad: Option<f64>,
    /// The last position the simulator reported (NED about home, m).
    pub final_pos_ned_m: [f64; 3],
    /// Its distance from the mission's last set-point, m.
    pub final_error_m: Option<f64>,
    /// RMS distance from the reference while tracking a scenario, m (3-D).
    pub tracking_rmse_m: Option<f64>,
    /// Largest distance, while armed, between the vehicle's estimate
    /// (`LOCAL_POSITION_NED`, 50 Hz) and the simulator's position at that step, m.
    pub max_estimate_error_m: f64,
    /// MAVLink frames this process's readers refused (every kind).
    pub refused_frames: u32,
    /// The vehicle's last `SYS_STATUS`: `errors_count1..4` (refused
    /// sensor samples, parameter writes, commands, invalid values).
    pub vehicle_errors: [u16; 4],
    /// Whether the ground station's link ended the flight signing (a key
    /// set by `SETUP_SIGNING`). These four figures are this process's
    /// link's (in process); the image in QEMU checks signatures itself and
    /// logs what it dropped (`firmware_log`), so there they stay zero.
    pub signing_on: bool,
    /// The ground station's frames the signing check dropped: unsigned,
    /// badly signed, replayed, too many streams.
    pub signing_dropped: [u32; 4],
    /// Signed frames the signing check accepted.
    pub signing_accepted: u32,
    /// `SETUP_SIGNING` requests refused (armed, or not signed with the key).
    pub signing_setups_refused: u32,
    /// What the controllers flew: `estimate` (the estimator's, from the
    /// simulated sensors) or `truth` (the simulator's `ODOMETRY`).
    pub state: String,
    /// The simulator's true states flown (`--state truth`).
    pub truth_states: u64,
    /// The vehicle's `STATUSTEXT`s, in order.
    pub status_texts: Vec<String>,
    /// The settings store (`--storage`), if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub storage: Option<StorageSummary>,
    /// What ended the flight: its duration, or the simulator hanging up
    /// (closed or reset), with the steps flown.
    pub end: String,
    /// The image's defmt log (QEMU).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub firmware_log: Vec<String>,
    /// Rows `[t, north, east, down (reported), north, east, down (estimate), setpoint n, e, d]`.
    #[serde(skip)]
    pub trace: Vec<[f64; 10]>,
}

/// Whether `e` is a peer that went away (closed, reset, aborted), which
/// ends a flight with its summary rather than failing it.
fn hung_up(e: &std::io::Error) -> bool {
    use std::io::ErrorKind::*;
    matches!(
        e.kind(),
        ConnectionReset | ConnectionAborted | BrokenPipe | UnexpectedEof
    )
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

/// Who gets a message the vehicle sent: the simulator its motor commands,
/// both its heartbeat, the ground station everything else (as PX4 routes
/// them; the image has one link for both).
fn route(msg: &MavMessage) -> (bool, bool) {
    match msg {
        MavMessage::HIL_ACTUATOR_CONTROLS(_) => (true, false),
        MavMessage::HEARTBEAT(_) => (true, true),
        _ => (false, true),
    }
}

/// The flight controller, wherever it runs: messages in, what it sent back out.
trait Vehicle {
    /// Hands `msg` to the vehicle; what it sent in answer is appended to
    /// `out`. A `HIL_SENSOR` returns with its `HIL_ACTUATOR_CONTROLS`.
    fn deliver(&mut self, msg: &MavMessage, out: &mut Vec<MavMessage>) -> Result<()>;
    /// [`Vehicle::deliver`] for the ground station's messages (`frame`: as
    /// the ground station sent it, signature included). In process the
    /// link signs with `signing` (a `SETUP_SIGNING` sets it); the image in
    /// QEMU gets `frame` unchanged and checks it itself.
    fn deliver_from_gcs(
        &mut self,
        msg: &MavMessage,
        frame: &[u8],
        out: &mut Vec<MavMessage>,
        signing: &mut Signing,
    ) -> Result<()>;
    /// Whether it sends the ground station's messages itself, as it wrote
    /// them (the image in QEMU: signed by the image), rather than the host
    /// encoding them.
    fn relays_gcs(&self) -> bool {
        false
    }
    /// Frames its readers refused.
    fn refused(&self) -> u32;
    /// Stores the ground station link's signing key and timestamp where
    /// the vehicle keeps its settings (in process, with `--storage`).
    fn keep_signing(&mut self, _signing: &Signing) -> Result<(), fc_storage::StoreError> {
        Ok(())
    }
    /// Flies `truth` in place of its estimate (see [`HilConfig::truth_state`]).
    fn fly_truth(&mut self, _truth: StateEstimate<f32>) -> Result<()> {
        bail!("only the flight controller in this process can fly the true state")
    }
    /// Hands it a trajectory to fly from `start_us` (the simulator's µs),
    /// as if uploaded ([`Mission::Trajectory`]).
    fn fly_trajectory(&mut self, _flown: &trajectory::Flown, _start_us: u64) -> Result<()> {
        bail!("only the flight controller in this process takes a trajectory (MAVLink uploads none)")
    }
    /// Ends it; the image's log.
    fn finish(self: Box<Self>) -> Result<Vec<String>>;
}

fn status_text(m: &MavMessage) -> Option<String> {
    match m {
        MavMessage::STATUSTEXT(t) => {
            let len = t.text.iter().position(|&b| b == 0).unwrap_or(t.text.len());
            Some(String::from_utf8_lossy(&t.text[..len]).into_owned())
        }
        _ => None,
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
/// acceleration, yaw, yaw rate; the jerk has no field). Without a
/// `heading_rad` the heading is masked: the vehicle keeps the one it holds
/// (on the ground, its own).
pub fn position_target(sp: &Setpoint<f32>, heading_rad: Option<f32>, t_ms: u32) -> MavMessage {
    let type_mask = match heading_rad {
        Some(_) => common::PositionTargetTypemask::empty(),
        None => common::PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_IGNORE,
    };
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
        yaw: heading_rad.unwrap_or(0.0),
        yaw_rate: sp.yaw_rate_radps,
        type_mask,
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

/// `MAV_CMD_DO_SET_MODE` to PX4's Offboard, as MAVSDK sends it.
pub fn offboard_command() -> MavMessage {
    let (main, sub) = fc_mavlink::modes::Px4Mode::px4(fc_mavlink::modes::FlightMode::Offboard);
    MavMessage::COMMAND_LONG(common::COMMAND_LONG_DATA {
        param1: f32::from(common::MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits()),
        param2: f32::from(main),
        param3: f32::from(sub),
        command: common::MavCmd::MAV_CMD_DO_SET_MODE,
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
    cfg.settings
        .check()
        .map_err(|e| anyhow::anyhow!("the vehicle's parameters are refused: {e}"))?;
    let mut res = HilResult {
        state: if cfg.truth_state { "truth" } else { "estimate" }.into(),
        ..HilResult::default()
    };
    let gcs = match cfg.gcs {
        Some(addr) => {
            let sock = UdpSocket::bind("0.0.0.0:0").context("opening the ground station's UDP socket")?;
            sock.set_nonblocking(true)?;
            Some((sock, addr))
        }
        None => None,
    };
    // The ground station's link: signed once a SETUP_SIGNING sets a key
    // (PX4's rules, fc_mavlink::signing), or from the start with a key
    // kept in --storage; the simulator's is never signed (PX4's simulator
    // interface is not its MAVLink module).
    let mut gcs_signing = Signing::new();
    let mut v: Box<dyn Vehicle> = match &cfg.target {
        Target::InProcess => {
            res.target = "in-process".into();
            let (mut store, mut settings) = (None, cfg.settings);
            if let Some(path) = &cfg.storage {
                let (mut st, boot) = crate::storage::open(path, "px4-hil")?;
                let loaded = fc_loop::params::load(settings, |i| st.param(i))
                    .map_err(|e| anyhow::anyhow!("--storage {}: {e}", path.display()))?;
                settings = loaded.settings;
                let mut sum = StorageSummary {
                    boot: boot.to_string(),
                    params_loaded: loaded.taken,
                    params_refused: loaded.refused.0,
                    ..Default::default()
                };
                if let Some(i) = loaded.refused.1 {
                    eprintln!(
                        "px4-hil: storage: {} stored value(s) refused, defaults kept (first: {})",
                        loaded.refused.0,
                        fc_mavlink::params::PARAMS[usize::from(i)].id
                    );
                }
                if let Some((key, ts)) = st.signing().map_err(|e| anyhow::anyhow!("--storage: {e}"))? {
                    if key != [0; 32] {
                        gcs_signing = Signing::stored(key, ts);
                        sum.key_loaded = true;
                        sum.timestamps[0] = ts;
                    }
                }
                res.storage = Some(sum);
                store = Some(st);
            }
            let mut v = MavVehicle::new(settings, SYSTEM_ID)
                .map_err(|e| anyhow::anyhow!("the vehicle's parameters are refused: {e}"))?;
            v.set_exact_preview(cfg.exact_preview);
            if let Some(sum) = res.storage.as_ref() {
                eprintln!(
                    "px4-hil: storage: {} parameter(s) taken, {} refused; signing key: {}",
                    sum.params_loaded,
                    sum.params_refused,
                    if sum.key_loaded { "kept, signing on" } else { "none" }
                );
            }
            Box::new(InProcess {
                v,
                clock: hal_shim::host::MonotonicClock::default(),
                wall: Instant::now(),
                store,
            })
        }
        Target::Qemu(_) if !cfg.exact_preview => {
            bail!("the preview is switched off in process only: the image flies its own")
        }
        Target::Qemu(_) if cfg.storage.is_some() => {
            bail!("--storage is for the in-process vehicle: the image in QEMU keeps its own (a RAM stand-in)")
        }
        Target::Qemu(elf) => {
            res.target = "qemu".into();
            let mut q = InQemu::start(elf)?;
            write_parameters(&mut q, &cfg.settings)?;
            if let Some((sock, addr)) = &gcs {
                q.gcs = Some((sock.try_clone()?, *addr));
            }
            Box::new(q)
        }
    };
    let mut ulog = match &cfg.ulog {
        Some(path) => Some(crate::flight_log::HilULog::create(path, &cfg.settings)?),
        None => None,
    };
    let stream = connect(&cfg.addr, cfg.connect_timeout_s)?;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_secs(60)))?;
    let mut sim = stream.try_clone()?;
    let (mut sim_seq, mut gcs_seq) = (0u8, 0u8);
    let mut signing_clock = Instant::now();
    let mut send = |to_sim: bool, msg: &MavMessage, sim: &mut TcpStream, signing: &mut Signing| -> Result<()> {
        let seq = if to_sim { &mut sim_seq } else { &mut gcs_seq };
        let header = MavHeader {
            system_id: u32::from(SYSTEM_ID),
            component_id: COMPONENT_ID,
            sequence: *seq,
        };
        *seq = seq.wrapping_add(1);
        let mut out = [0u8; MAX_FRAME];
        let n = if to_sim {
            encode(header, msg, &mut out)
        } else {
            match encode_signed(header, msg, &mut out, signing) {
                // Booted on a stored key: nothing goes out until the owner is heard.
                Err(fc_mavlink::MavError::Unclocked) => return Ok(()),
                r => r,
            }
        }
        .map_err(|e| anyhow::anyhow!("{e}"))?;
        if to_sim {
            match sim.write_all(&out[..n]) {
                // Its hang-up ends the flight where the reader sees it.
                Err(e) if hung_up(&e) => Ok(()),
                r => r.context("writing to the simulator"),
            }
        } else {
            if let Some((sock, addr)) = &gcs {
                // A ground station that has gone away is not an error of the flight.
                let _ = sock.send_to(&out[..n], addr);
            }
            Ok(())
        }
    };
    send(
        true,
        &MavMessage::HEARTBEAT(fc_mavlink::hil::heartbeat(
            false,
            fc_mavlink::modes::Px4Mode::custom_mode(fc_mavlink::modes::FlightMode::Position),
        )),
        &mut sim,
        &mut gcs_signing,
    )?;
    let mut input = stream;
    let mut sim_reader = MavReader::new(SYSTEM_ID);
    let mut gcs_reader = MavReader::new(SYSTEM_ID);
    let (mut sq_sum, mut sq_n) = (0.0, 0usize);
    let (mut t0_us, mut next_arm_s, mut next_sp_s, mut armed) = (None::<u64>, 0.0, 0.0, false);
    // A trajectory mission's pieces handed to the vehicle (from then on
    // nothing is streamed: it flies them on board).
    let mut handed_over = false;
    // The set-point last sent, and the mission's reference now.
    let (mut home, mut truth, mut sp) = (None, Vector3::<f64>::zeros(), None::<Setpoint<f32>>);
    let mut reference = None::<Setpoint<f32>>;
    // Simulated time of the last HIL_SENSOR (the log's clock), the last
    // attitude estimate's heading, and the arming state last logged.
    let (mut t_now, mut est_yaw, mut logged_armed) = (0.0f64, 0.0f32, None::<bool>);
    let mut buf = [0u8; 4096];
    let mut dgram = [0u8; 2048];
    let mut out = Vec::new();
    let gcs_sock = match &gcs {
        Some((sock, _)) => Some(sock.try_clone()?),
        None => None,
    };
    'flight: loop {
        // The ground station's datagrams first (never blocks).
        if let Some(sock) = &gcs_sock {
            let now = Instant::now();
            gcs_signing.advance_us((now - signing_clock).as_micros() as u64);
            signing_clock = now;
            while let Ok(n) = sock.recv(&mut dgram) {
                for &b in &dgram[..n] {
                    if let Some(Ok((_, msg))) = gcs_reader.push_signed(b, &mut gcs_signing) {
                        v.deliver_from_gcs(&msg, gcs_reader.frame(), &mut out, &mut gcs_signing)?;
                    }
                }
            }
        }
        let n = match input.read(&mut buf) {
            Ok(0) => {
                res.end = format!("the simulator closed the connection after {} steps", res.steps);
                break;
            }
            Ok(n) => n,
            Err(e) if hung_up(&e) => {
                res.end = format!("the simulator hung up after {} steps ({e})", res.steps);
                break;
            }
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
            let msg = match sim_reader.push(b) {
                Some(Ok((_, msg))) => msg,
                Some(Err(fc_mavlink::MavError::Unused(ODOMETRY_ID))) if cfg.truth_state => {
                    v.fly_truth(truth_from_odometry(sim_reader.frame())?)?;
                    res.truth_states += 1;
                    continue;
                }
                _ => continue,
            };
            if let MavMessage::HIL_STATE_QUATERNION(m) = &msg {
                if fc_mavlink::hil::on_earth(m) {
                    let h = *home.get_or_insert(fc_mavlink::hil::Home::of(m));
                    truth = h.ned_m(m.lat, m.lon, m.alt);
                    if let Some(log) = ulog.as_mut() {
                        let p = [truth[0] as f32, truth[1] as f32, truth[2] as f32];
                        let v = [m.vx, m.vy, m.vz].map(|c| f32::from(c) * 0.01);
                        log.truth(t_now, p, v, m.attitude_quaternion)?;
                    }
                }
            }
            let MavMessage::HIL_SENSOR(m) = &msg else {
                v.deliver(&msg, &mut out)?;
                continue;
            };
            let t0 = *t0_us.get_or_insert(m.time_usec);
            let t = m.time_usec.saturating_sub(t0) as f64 * 1e-6;
            t_now = t;
            // The mission, sent as a ground station sends it: the set-point
            // when it changes, at most at 100 Hz (a trajectory's moves, with
            // its velocity and acceleration), and at least every 0.2 s (an
            // Offboard stream: PX4 leaves Offboard when it stops for 1 s);
            // arming every 0.5 s until armed.
            //
            // The mission's headings are about the take-off heading, as a
            // ground station flies a pattern about the vehicle's heading:
            // until armed the heading is masked (the vehicle keeps its own),
            // then it is the vehicle's estimate at arming plus the mission's.
            let mut tracking = false;
            let takeoff_yaw = res.takeoff_heading_rad.map(|h| h as f32);
            if let Some(mission) = &cfg.mission {
                let (mut s, track) = mission.setpoint_at(t);
                tracking = track;
                if let (Some(h), false) = (takeoff_yaw, mission.absolute_heading()) {
                    s.yaw_rad = fc_core::control::wrap_pi(s.yaw_rad + h);
                }
                reference = Some(s);
                if let Mission::Trajectory(flown) = mission {
                    if t >= flown.from_s - 1e-9 && !handed_over {
                        if !armed {
                            bail!(
                                "the trajectory was to start at {} s, and the vehicle is not armed",
                                flown.from_s
                            );
                        }
                        v.fly_trajectory(flown, t0 + (flown.from_s * 1e6).round() as u64)?;
                        handed_over = true;
                    }
                }
                let changed = sp.is_none_or(|old| old != s);
                let due = (changed && t >= next_sp_s - 1e-9) || t >= next_sp_s + SETPOINT_REPEAT_S;
                if due && !handed_over {
                    let heading = takeoff_yaw.map(|_| s.yaw_rad);
                    v.deliver(&position_target(&s, heading, (t * 1e3) as u32), &mut out)?;
                    if let Some(log) = ulog.as_mut() {
                        log.setpoint(t, &s)?;
                    }
                    next_sp_s = t + SETPOINT_PERIOD_S;
                    sp = Some(s);
                }
                if !armed && t >= next_arm_s {
                    // PX4's order: Offboard (the set-points stream), then arm.
                    v.deliver(&offboard_command(), &mut out)?;
                    v.deliver(&arm_command(true), &mut out)?;
                    next_arm_s = t + 0.5;
                }
            }
            v.deliver(&msg, &mut out)?;
            res.steps += 1;
            res.duration_s = t;
            let spn = reference.map_or(Vector3::repeat(f64::NAN), |s| s.pos_ned_m.cast::<f64>());
            if tracking {
                sq_sum += (truth - spn).norm_squared();
                sq_n += 1;
            }
            for m in out.drain(..) {
                match &m {
                    MavMessage::HEARTBEAT(h) => {
                        armed = h.base_mode.contains(common::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
                    }
                    MavMessage::LOCAL_POSITION_NED(p) => {
                        let est = Vector3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                        if let Some(log) = ulog.as_mut() {
                            log.position(t, [p.x, p.y, p.z], [p.vx, p.vy, p.vz], est_yaw)?;
                        }
                        if armed {
                            res.max_estimate_error_m = res.max_estimate_error_m.max((est - truth).norm());
                        }
                        res.trace.push([
                            t, truth[0], truth[1], truth[2], est[0], est[1], est[2], spn[0], spn[1], spn[2],
                        ]);
                    }
                    MavMessage::ATTITUDE(a) => {
                        est_yaw = a.yaw;
                        if let Some(log) = ulog.as_mut() {
                            let q = fc_core::euler_to_quat(a.roll, a.pitch, a.yaw);
                            log.attitude(t, [q[0], q[1], q[2], q[3]])?;
                        }
                    }
                    MavMessage::HIL_ACTUATOR_CONTROLS(c) => {
                        if let Some(log) = ulog.as_mut() {
                            log.outputs(t, &c.controls[..4])?;
                        }
                    }
                    MavMessage::PARAM_VALUE(pv) => {
                        if let Some(log) = ulog.as_mut() {
                            if let Ok(name) = pv.param_id.to_str() {
                                log.param(name.trim_end_matches('\0'), pv.param_value)?;
                            }
                        }
                    }
                    MavMessage::SYS_STATUS(st) => {
                        res.vehicle_errors = [st.errors_count1, st.errors_count2, st.errors_count3, st.errors_count4];
                    }
                    MavMessage::STATUSTEXT(_) => {
                        let text = status_text(&m).unwrap_or_default();
                        if text == "armed" {
                            armed = true;
                        }
                        if let (Some(log), MavMessage::STATUSTEXT(st)) = (ulog.as_mut(), &m) {
                            let warning = st.severity as u8 <= common::MavSeverity::MAV_SEVERITY_WARNING as u8;
                            log.text(t, warning, &text)?;
                        }
                        res.status_texts.push(text);
                    }
                    _ => {}
                }
                if armed && res.armed_at_s.is_none() {
                    res.armed_at_s = Some(t);
                    res.takeoff_heading_rad = Some(f64::from(est_yaw));
                }
                if let Some(log) = ulog.as_mut() {
                    if logged_armed != Some(armed) || matches!(m, MavMessage::HEARTBEAT(_)) {
                        log.status(t, armed)?;
                        logged_armed = Some(armed);
                    }
                }
                let (to_sim, to_gcs) = route(&m);
                if to_sim {
                    send(true, &m, &mut sim, &mut gcs_signing)?;
                }
                if to_gcs && !v.relays_gcs() {
                    send(false, &m, &mut sim, &mut gcs_signing)?;
                }
            }
            if t >= cfg.duration_s {
                res.end = format!("the flight's duration, {} s", cfg.duration_s);
                break 'flight;
            }
        }
    }
    res.refused_frames = sim_reader.counters().refused() + gcs_reader.counters().refused() + v.refused();
    let sc = gcs_signing.counters();
    res.signing_on = gcs_signing.is_on();
    res.signing_dropped = [sc.unsigned, sc.bad_signature, sc.replayed, sc.too_many_streams];
    res.signing_accepted = sc.accepted;
    res.signing_setups_refused = sc.setups_refused;
    // The timestamp goes on from here at the next boot.
    let kept = v.keep_signing(&gcs_signing);
    if let Some(sum) = res.storage.as_mut() {
        match kept {
            Ok(()) => sum.timestamps[1] = gcs_signing.key().map_or(0, |_| gcs_signing.timestamp()),
            Err(e) => {
                eprintln!("px4-hil: storage: the signing timestamp is not stored: {e}");
                sum.error = Some(e.to_string());
            }
        }
    }
    res.firmware_log = v.finish()?;
    if let Some(log) = ulog {
        log.finish()?;
    }
    res.final_pos_ned_m = truth.into();
    res.tracking_rmse_m = (sq_n > 0).then(|| (sq_sum / sq_n as f64).sqrt());
    res.final_error_m = reference.map(|s| (truth - s.pos_ned_m.cast::<f64>()).norm());
    Ok(res)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::MAVLinkV2MessageRaw;

    /// An `ODOMETRY` frame as a simulator writes it (the `mavlink` crate's
    /// encoder), in `frame_id`.
    fn odometry(frame_id: common::MavFrame, x: f32) -> Vec<u8> {
        let (c, s) = (core::f32::consts::FRAC_PI_4.cos(), core::f32::consts::FRAC_PI_4.sin());
        let m = common::ODOMETRY_DATA {
            time_usec: 1_000_000,
            x,
            y: -2.0,
            z: -1.0,
            // Heading 90° (east), level: body FRD → NED.
            q: [c, 0.0, 0.0, s],
            vx: 1.0,
            vy: 0.0,
            vz: 0.0,
            rollspeed: 0.1,
            pitchspeed: -0.2,
            yawspeed: 0.3,
            pose_covariance: [f32::NAN; 21],
            velocity_covariance: [f32::NAN; 21],
            frame_id,
            child_frame_id: common::MavFrame::MAV_FRAME_BODY_FRD,
        };
        let mut raw = MAVLinkV2MessageRaw::new();
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        };
        raw.serialize_message_data(header, &m);
        raw.raw_bytes().to_vec()
    }

    #[test]
    fn odometry_is_the_true_state_in_ned() {
        let t = truth_from_odometry(&odometry(common::MavFrame::MAV_FRAME_LOCAL_NED, 1.5)).unwrap();
        assert_eq!(t.pos_ned_m, Vector3::new(1.5, -2.0, -1.0));
        // Forward in the body, facing east: east in NED.
        assert!(
            (t.vel_ned_mps - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-6,
            "{:?}",
            t.vel_ned_mps
        );
        assert!((t.euler()[2] - core::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert_eq!(t.rates_frd_radps, Vector3::new(0.1, -0.2, 0.3));
    }

    #[test]
    fn odometry_in_another_frame_or_not_finite_is_refused_by_name() {
        let enu = truth_from_odometry(&odometry(common::MavFrame::MAV_FRAME_LOCAL_ENU, 1.5)).unwrap_err();
        assert!(enu.to_string().contains("MAV_FRAME_LOCAL_NED"), "{enu}");
        let nan = truth_from_odometry(&odometry(common::MavFrame::MAV_FRAME_LOCAL_NED, f32::NAN)).unwrap_err();
        assert!(nan.to_string().contains("not finite"), "{nan}");
        let frame = odometry(common::MavFrame::MAV_FRAME_LOCAL_NED, 1.5);
        assert!(truth_from_odometry(&frame[..20]).is_err());
    }
}
