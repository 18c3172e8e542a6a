//! The flight controller as a MAVLink vehicle: [`MavVehicle`] takes the
//! messages of a simulator (PX4's HIL interface) and of a ground station,
//! runs the flight loop ([`fc_loop::FlightCore`]) on them, and answers.
//!
//! - `HIL_SENSOR` → one estimator step (the controller on its schedule),
//!   answered by one `HIL_ACTUATOR_CONTROLS` (lockstep): the motor
//!   commands of the mixer the parameters describe, zero while disarmed.
//!   Its time (`time_usec`) is the loop's clock (lockstep): a gap longer
//!   than `FS_TIMEOUT_MS` is a failsafe episode, as on our own protocol.
//! - `HIL_STATE_QUATERNION` → a position and heading fix every
//!   `HIL_FIX_MS` (a mocap-like source; its velocity is not used). Its
//!   first position is home, the origin of the local NED frame.
//! - `COMMAND_LONG` `MAV_CMD_COMPONENT_ARM_DISARM` → arm (refused while the
//!   estimator aligns or is in its failsafe) or disarm; `COMMAND_ACK` and a
//!   `STATUSTEXT` answer. Arming designs the controller afresh (no state
//!   wound up on the ground) and, unless a set-point came first, holds the
//!   position armed at. Disarming in the air (more than [`IN_AIR_M`] above
//!   where it armed) is refused unless forced (`param2` = 21196), as PX4 does.
//! - Ground-station loss (`FS_GCS_MS`, once a `HEARTBEAT` of type
//!   `MAV_TYPE_GCS` has been heard): armed and silent that long → land
//!   where it is and disarm on the ground.
//! - `SET_POSITION_TARGET_LOCAL_NED` (`MAV_FRAME_LOCAL_NED`, position
//!   given; velocity, acceleration, yaw and yaw rate when not masked) → the
//!   set-point (feed-forward as given).
//! - The parameter protocol over [`params::PARAMS`]; a refused
//!   `PARAM_SET` is answered with the unchanged value and a `STATUSTEXT`
//!   saying why.
//! - Telemetry on simulated time: `HEARTBEAT` 1 Hz (to both peers),
//!   `SYS_STATUS` 2 Hz, `ATTITUDE` and `LOCAL_POSITION_NED` 50 Hz.
//!
//! Anything else (other systems' messages, unknown commands) is counted
//! and answered where MAVLink expects an answer (`MAV_RESULT_UNSUPPORTED`).

use crate::hil::{self, Home, StateFixSigmas};
use crate::mission::{Mission, Step, MISSION_CAPACITY};
use crate::modes::{joystick_velocity, nav_index_of, FlightMode, Legs, NavSettings, Route, NAV_PARAMS};
use crate::params::{self, Refusal, Settings, PARAMS};
use crate::MavMessage;
use core::convert::Infallible;
use fc_core::control::Setpoint;
use fc_core::estimate::Fix;
use fc_core::model::airframe::Mixer;
#[cfg(test)]
use fc_core::model::airframe::MixerError;
use fc_loop::baro::Barometer;
use fc_loop::nav::NavMode;
use fc_loop::planner::Reference;
use fc_loop::schedule::Schedule;
use fc_loop::{FcConfig, FlightCore, Outbox};
use fc_proto::FromFc;
use hal_shim::CycleClock;
use mavlink::dialects::common::*;
use nalgebra::{Vector3, Vector4};

/// Who a message is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Peer {
    /// The simulator (HIL_ACTUATOR_CONTROLS).
    Simulator,
    /// The ground station (telemetry, acknowledgements, parameters).
    GroundStation,
}

/// Where [`MavVehicle`]'s messages go (one link for both peers on the
/// image; a TCP and a UDP socket on the host).
pub trait MavSink {
    /// What sending can fail with.
    type Error;
    /// Sends `msg` to `to`.
    fn send(&mut self, to: Peer, msg: &MavMessage) -> Result<(), Self::Error>;
    /// The ground station link's signing state, if this link signs (a
    /// `SETUP_SIGNING` changes it; `None`: the request is ignored).
    fn signing(&mut self) -> Option<&mut crate::signing::Signing> {
        None
    }
    /// Where settings persist across a reboot, if anywhere: a parameter a
    /// ground station sets is stored there at once (as PX4 saves its
    /// parameters), and a signing key when `SETUP_SIGNING` sets it.
    /// `None`: they live until power-off.
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        None
    }
}

/// What the vehicle did with what it got.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VehicleCounters {
    /// `HIL_SENSOR` steps flown.
    pub steps: u32,
    /// `HIL_SENSOR`s refused (inertial fields not flagged, not finite).
    pub sensors_refused: u32,
    /// `HIL_STATE_QUATERNION`s refused (non-unit attitude).
    pub states_refused: u32,
    /// Steps on which the mixer clamped a motor (armed).
    pub clamped_steps: u32,
    /// Set-points refused (frame, mask, not finite).
    pub setpoints_refused: u32,
    /// Commands refused or not supported.
    pub commands_refused: u32,
    /// Parameter writes refused.
    pub params_refused: u32,
    /// Messages this vehicle has no use for.
    pub ignored: u32,
    /// Barometer readings fused (flagged in `HIL_SENSOR`).
    pub baro_fixes: u32,
    /// Magnetometer headings fused (flagged in `HIL_SENSOR`).
    pub mag_fixes: u32,
}

/// Height above the arming point from which the vehicle is in the air, m.
pub const IN_AIR_M: f32 = 0.15;
/// Within this of the height it armed at, a landing vehicle has landed, m.
pub const LANDED_M: f32 = 0.03;
/// Slower than this vertically (estimated), a landing vehicle on the ground has landed, m/s.
pub const LANDED_MPS: f32 = 0.2;
/// `param2` of a disarm that is obeyed in the air too (MAVLink's magic number).
const FORCE: f32 = 21196.0;

/// The telemetry streams and their default intervals, µs of simulated
/// time (`MAV_CMD_SET_MESSAGE_INTERVAL` changes them): message id, interval.
pub const STREAMS: [(u32, u64); 10] = [
    (0, 1_000_000),   // HEARTBEAT, 1 Hz (to the simulator too)
    (1, 500_000),     // SYS_STATUS, 2 Hz
    (30, 20_000),     // ATTITUDE, 50 Hz
    (32, 20_000),     // LOCAL_POSITION_NED, 50 Hz
    (33, 100_000),    // GLOBAL_POSITION_INT, 10 Hz
    (31, 100_000),    // ATTITUDE_QUATERNION, 10 Hz
    (245, 200_000),   // EXTENDED_SYS_STATE, 5 Hz
    (242, 2_000_000), // HOME_POSITION, 0.5 Hz
    (42, 1_000_000),  // MISSION_CURRENT, 1 Hz
    (230, 500_000),   // ESTIMATOR_STATUS, 2 Hz
];
/// The shortest interval a stream may be set to, µs (the IMU's step).
pub const MIN_INTERVAL_US: u64 = 1_000;
/// `AUTOPILOT_VERSION` (148), sent when asked for.
const AUTOPILOT_VERSION_ID: u32 = 148;
/// This firmware's version in PX4's encoding (major, minor, patch, 255 for
/// a release): the crates' version, 0.1.0.
pub const FLIGHT_SW_VERSION: u32 = 0x0001_00FF;
/// A flagged `HIL_SENSOR` barometer (and magnetometer) is fused at most
/// this often, µs (50 Hz; `HIL_SENSOR` comes at the IMU's rate).
pub const BARO_PERIOD_US: u64 = fc_loop::baro::PERIOD_US;
/// 1σ assumed of a barometric height, m.
pub const BARO_SIGMA_M: f32 = fc_loop::baro::SIGMA_M;
/// 1σ assumed of a magnetometer heading, rad (2°).
pub const MAG_SIGMA_RAD: f32 = 0.035;

/// The flight loop's answers to one `Imu` step, kept.
#[derive(Default)]
struct Answer {
    u: Option<[f32; 4]>,
    cycles: u32,
}

impl Outbox for Answer {
    type Error = Infallible;
    fn send(&mut self, msg: &FromFc) -> Result<(), Infallible> {
        match msg {
            FromFc::Actuator { u, .. } => self.u = Some(*u),
            FromFc::Telemetry { cycles, .. } => self.cycles = *cycles,
            _ => {}
        }
        Ok(())
    }
}

/// A 50-byte `STATUSTEXT` being written.
struct Text {
    buf: [u8; 50],
    len: usize,
}

impl core::fmt::Write for Text {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for &b in s.as_bytes() {
            if self.len < self.buf.len() {
                self.buf[self.len] = b;
                self.len += 1;
            }
        }
        Ok(())
    }
}

/// The flight controller behind MAVLink (see the module's documentation).
pub struct MavVehicle {
    core: FlightCore,
    /// `None` until started.
    mixer: Option<Mixer<f32>>,
    armed: bool,
    /// Simulated time of the last ground-station `HEARTBEAT`, µs.
    gcs_seen_us: Option<u64>,
    /// The flight mode ([`crate::modes`]).
    mode: FlightMode,
    /// The automatic modes' settings (PX4's parameters).
    nav: NavSettings,
    /// The automatic mode's route.
    route: Route,
    /// The mission store and its transfers.
    mission: Mission,
    /// The mission item flown (Mission mode).
    mission_phase: Option<MissionPhase>,
    /// A mission's `DO_CHANGE_SPEED`, for the rest of it.
    mission_cruise_mps: Option<f32>,
    /// The last offboard set-point, and when it came (simulated µs).
    offboard: Option<(Setpoint<f32>, u64)>,
    /// The last streamed acceleration and its sender's time
    /// (`time_boot_ms`), for the jerk the message has no field for.
    offboard_acc: Option<(Vector3<f32>, u32)>,
    /// The joystick's last `MANUAL_CONTROL` (x, y, z, r), and when it came.
    manual: Option<([i16; 4], u64)>,
    /// Where it armed (estimated), NED about the origin, m: the home a
    /// return flies to (the origin until it arms).
    home_ned_m: Vector3<f32>,
    /// The simulator's first position: the origin of the local frame.
    home: Option<Home>,
    /// Time of the last fix taken, µs.
    last_fix_us: Option<u64>,
    /// The `HIL_SENSOR` barometer: its reference (the first reading
    /// referenced to the estimated height then) and rate.
    baro: Barometer,
    /// Magnetic heading minus true heading (the declination, and whatever
    /// the simulator's field adds), rad: the first reading referenced to
    /// the estimated heading then.
    mag_ref_rad: Option<f32>,
    /// When a magnetometer heading is next fused (every [`BARO_PERIOD_US`]).
    mag_due: Schedule,
    /// Time of the last `HIL_SENSOR`, µs.
    last_sensor_us: Option<u64>,
    /// The `Imu` sequence number.
    seq: u32,
    /// Motor commands of the last step.
    motors: [f32; 4],
    /// Cycles of the last step, and the clock's rate.
    cycles: (u32, u32),
    /// The telemetry streams: interval (µs, 0: off) and next time due, in
    /// [`STREAMS`]' order.
    streams: [(u64, u64); STREAMS.len()],
    /// Frames the links' readers refused (for `SYS_STATUS.errors_comm`).
    link_errors: u32,
    /// Position last reported by the simulator, NED about home, m.
    reported_ned_m: Option<Vector3<f64>>,
    counters: VehicleCounters,
    system_id: u8,
}

/// Milliseconds since boot of simulated time `t_us` (MAVLink's `time_boot_ms`).
fn boot_ms(t_us: u64) -> u32 {
    (t_us / 1000) as u32
}

/// Every parameter served: the flight loop's ([`PARAMS`]), then the
/// automatic modes' ([`NAV_PARAMS`]).
pub const PARAM_COUNT: usize = PARAMS.len() + NAV_PARAMS.len();

/// The `param_index` of the parameter named `id` (NUL-padded), in either table.
pub fn param_index_of(id: &[u8]) -> Option<usize> {
    params::index_of(id).or_else(|| nav_index_of(id).map(|k| PARAMS.len() + k))
}

/// The name of parameter `index` (of [`PARAM_COUNT`]).
fn param_id(index: usize) -> &'static str {
    match PARAMS.get(index) {
        Some(p) => p.id,
        None => NAV_PARAMS.get(index - PARAMS.len()).map_or("?", |p| p.id),
    }
}

/// The mission item flown.
#[derive(Debug, Clone, Copy, PartialEq)]
enum MissionPhase {
    /// Flying to `goal` (NED, m); reached within `accept_m`, then held `hold_s`.
    Flying {
        seq: u16,
        goal: Vector3<f32>,
        accept_m: f32,
        hold_s: f32,
    },
    /// Holding until `until_us`.
    Holding { seq: u16, until_us: u64 },
}

/// A command, from `COMMAND_LONG` or `COMMAND_INT` (its x and y as f32).
struct Command {
    command: MavCmd,
    params: [f32; 7],
}

impl MavVehicle {
    /// A vehicle with `settings` (checked; the controller designed), MAVLink
    /// system `system_id`, disarmed, its estimator waiting for samples.
    pub fn new(settings: Settings, system_id: u8) -> Result<Self, Refusal> {
        let mut v = Self::unstarted(settings, system_id);
        v.start()?;
        Ok(v)
    }

    /// The vehicle with nothing designed yet (motors off until
    /// [`MavVehicle::start`] succeeds). The firmware constructs it this way,
    /// in its static home, so that the design does not run beneath a stack
    /// copy of the whole vehicle (its controller is ≈ 7 KiB).
    pub fn unstarted(settings: Settings, system_id: u8) -> Self {
        Self {
            core: FlightCore::unstarted_with(FcConfig::default(), settings),
            mixer: None,
            armed: false,
            gcs_seen_us: None,
            mode: FlightMode::Position,
            nav: NavSettings::default(),
            route: Route::new(),
            mission: Mission::new(),
            mission_phase: None,
            mission_cruise_mps: None,
            offboard: None,
            offboard_acc: None,
            manual: None,
            home_ned_m: Vector3::zeros(),
            home: None,
            last_fix_us: None,
            baro: Barometer::new(),
            mag_ref_rad: None,
            mag_due: Schedule::new(),
            last_sensor_us: None,
            seq: 0,
            motors: [0.0; 4],
            cycles: (0, 1),
            streams: STREAMS.map(|(_, us)| (us, 0)),
            link_errors: 0,
            reported_ned_m: None,
            counters: VehicleCounters::default(),
            system_id,
        }
    }

    /// Checks the settings and designs the controller in place; the
    /// session is open from then on (set-points may come before samples).
    pub fn start(&mut self) -> Result<(), Refusal> {
        self.mixer = Some(self.core.start_front_end()?);
        Ok(())
    }

    /// Armed (the motors turn).
    pub fn armed(&self) -> bool {
        self.armed
    }

    /// The settings in force (the parameters' values).
    pub fn settings(&self) -> &Settings {
        self.core.settings()
    }

    /// The flight loop (its estimator, set-point, counters).
    pub fn core(&self) -> &FlightCore {
        &self.core
    }

    /// What was done with what arrived.
    pub fn counters(&self) -> VehicleCounters {
        self.counters
    }

    /// Flies `truth` (the simulator's true state, NED about home: the
    /// origin of `HIL_STATE_QUATERNION`'s first fix) in place of the
    /// estimate, from the estimator's alignment on: the controller alone,
    /// for measuring it against a peer given perfect state. Host builds
    /// only (`truth-state`); the images fly their estimate.
    #[cfg(feature = "truth-state")]
    pub fn fly_truth(&mut self, truth: fc_core::control::StateEstimate<f32>) {
        self.core.navigator_mut().set_truth(Some(truth));
    }

    /// The motor commands of the last step (zero while disarmed).
    pub fn motors(&self) -> [f32; 4] {
        self.motors
    }

    /// Where the simulator last said the vehicle is (NED about home, m):
    /// for the host's measurements, not used in flight.
    pub fn reported_position(&self) -> Option<Vector3<f64>> {
        self.reported_ned_m
    }

    /// Records how many frames the links' readers have refused in all
    /// (reported in `SYS_STATUS.errors_comm`).
    pub fn set_link_errors(&mut self, refused: u32) {
        self.link_errors = refused;
    }

    /// Handles one message from system `from_system`; answers go to `out`.
    /// `now_us` is the caller's clock (only a free-running loop uses it).
    // MISSION_REQUEST and MISSION_SET_CURRENT are deprecated, and sent.
    #[allow(deprecated)]
    pub fn handle<S: MavSink, C: CycleClock>(
        &mut self,
        msg: &MavMessage,
        out: &mut S,
        clock: &C,
        now_us: u64,
    ) -> Result<(), S::Error> {
        match msg {
            MavMessage::HIL_SENSOR(m) => self.on_sensor(m, out, clock, now_us),
            MavMessage::HIL_STATE_QUATERNION(m) => {
                self.on_state(m);
                Ok(())
            }
            MavMessage::COMMAND_LONG(m) if self.for_me(m.target_system) => {
                let c = Command {
                    command: m.command,
                    params: [m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7],
                };
                self.on_command(&c, out)
            }
            MavMessage::COMMAND_INT(m) if self.for_me(m.target_system) => {
                // x and y are integers (degrees × 1e7 in global frames);
                // none of the commands answered here reads them.
                let c = Command {
                    command: m.command,
                    params: [m.param1, m.param2, m.param3, m.param4, m.x as f32, m.y as f32, m.z],
                };
                self.on_command(&c, out)
            }
            MavMessage::SET_POSITION_TARGET_LOCAL_NED(m) => self.on_setpoint(m, out),
            // PX4's receiver turns SET_MODE into DO_SET_MODE (base mode,
            // main and sub mode from the custom mode), answered alike.
            MavMessage::SET_MODE(m) if self.for_me(m.target_system) => {
                let c = Command {
                    command: MavCmd::MAV_CMD_DO_SET_MODE,
                    params: [
                        f32::from(m.base_mode.bits()),
                        ((m.custom_mode >> 16) & 0xff) as f32,
                        (m.custom_mode >> 24) as f32,
                        0.0,
                        0.0,
                        0.0,
                        0.0,
                    ],
                };
                self.on_command(&c, out)
            }
            MavMessage::SETUP_SIGNING(m) if self.for_me(m.target_system) => {
                let armed = self.armed;
                let Some(s) = out.signing() else {
                    return Ok(());
                };
                let authenticated = s.last_authenticated();
                match s.setup(&m.secret_key, m.initial_timestamp, authenticated, armed) {
                    Ok(done) => {
                        let kept = (s.key().copied().unwrap_or([0; 32]), s.timestamp());
                        self.say(out, MavSeverity::MAV_SEVERITY_NOTICE, format_args!("{done}"))?;
                        // No key is kept as the all-zero key (PX4's blank key file).
                        match out.storage().map(|st| st.set_signing(&kept.0, kept.1)) {
                            Some(Err(e)) => self.say(
                                out,
                                MavSeverity::MAV_SEVERITY_ERROR,
                                format_args!("signing key not stored: {e}"),
                            ),
                            _ => Ok(()),
                        }
                    }
                    Err(why) => self.say(out, MavSeverity::MAV_SEVERITY_WARNING, format_args!("{why}")),
                }
            }
            MavMessage::MANUAL_CONTROL(m) if self.for_me(m.target) => {
                self.manual = Some(([m.x, m.y, m.z, m.r], self.last_sensor_us.unwrap_or(0)));
                Ok(())
            }
            MavMessage::MISSION_COUNT(_)
            | MavMessage::MISSION_ITEM_INT(_)
            | MavMessage::MISSION_REQUEST_LIST(_)
            | MavMessage::MISSION_REQUEST_INT(_)
            | MavMessage::MISSION_REQUEST(_)
            | MavMessage::MISSION_CLEAR_ALL(_)
            | MavMessage::MISSION_SET_CURRENT(_)
            | MavMessage::MISSION_ACK(_) => {
                let t_us = self.last_sensor_us.unwrap_or(0);
                if self.mode == FlightMode::Mission
                    && !matches!(
                        msg,
                        MavMessage::MISSION_REQUEST_LIST(_)
                            | MavMessage::MISSION_REQUEST_INT(_)
                            | MavMessage::MISSION_REQUEST(_)
                            | MavMessage::MISSION_ACK(_)
                    )
                {
                    // The mission flown is not changed under it: Hold first.
                    let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                }
                self.mission
                    .handle(msg, t_us, self.home.as_ref(), self.home_ned_m[2], out)?;
                Ok(())
            }
            MavMessage::PARAM_REQUEST_LIST(m) if self.for_me(m.target_system) => {
                for i in 0..PARAM_COUNT {
                    self.send_param(i, out)?;
                }
                Ok(())
            }
            MavMessage::PARAM_REQUEST_READ(m) if self.for_me(m.target_system) => {
                let index = if m.param_index >= 0 {
                    Some(m.param_index as usize).filter(|&i| i < PARAM_COUNT)
                } else {
                    param_index_of(&m.param_id[..])
                };
                match index {
                    Some(i) => self.send_param(i, out),
                    None => self.status(
                        out,
                        MavSeverity::MAV_SEVERITY_WARNING,
                        &m.param_id[..],
                        Refusal::Unknown,
                    ),
                }
            }
            MavMessage::PARAM_SET(m) if self.for_me(m.target_system) => self.on_param_set(m, out),
            MavMessage::HEARTBEAT(h) => {
                if h.mavtype == MavType::MAV_TYPE_GCS {
                    self.gcs_seen_us = Some(self.last_sensor_us.unwrap_or(0));
                }
                Ok(())
            }
            _ => {
                self.counters.ignored = self.counters.ignored.wrapping_add(1);
                Ok(())
            }
        }
    }

    /// `target` is this system (0: broadcast).
    fn for_me(&self, target: u8) -> bool {
        target == 0 || target == self.system_id
    }

    fn on_sensor<S: MavSink, C: CycleClock>(
        &mut self,
        m: &HIL_SENSOR_DATA,
        out: &mut S,
        clock: &C,
        now_us: u64,
    ) -> Result<(), S::Error> {
        let Ok(s) = hil::imu_from_hil_sensor(m) else {
            self.counters.sensors_refused = self.counters.sensors_refused.wrapping_add(1);
            return Ok(());
        };
        let mut answer = Answer::default();
        if self.last_sensor_us.is_none_or(|t| s.time_us < t) {
            // The first sample, or a simulator that started again: a new time line.
            self.core.open_session();
            self.home = None;
            self.last_fix_us = None;
            self.baro.reset();
            self.mag_ref_rad = None;
            self.mag_due.reset();
            for (k, st) in self.streams.iter_mut().enumerate() {
                *st = (STREAMS[k].1, s.time_us);
            }
        }
        let dt_s = self
            .last_sensor_us
            .map_or(0.0, |t| s.time_us.saturating_sub(t) as f32 * 1e-6);
        self.last_sensor_us = Some(s.time_us);
        if let Some(alt) = s.baro_alt_m {
            self.on_baro(s.time_us, alt);
        }
        if let Some(mag) = s.mag_frd_gauss {
            self.on_mag(s.time_us, &mag);
        }
        self.seq = self.seq.wrapping_add(1);
        let _ = self
            .core
            .imu_step(self.seq, s.time_us, &s.imu, &mut answer, clock, now_us);
        self.cycles = (answer.cycles, clock.hz());
        self.counters.steps = self.counters.steps.wrapping_add(1);
        let u = Vector4::from(answer.u.unwrap_or([0.0; 4]));
        let cmd = self.mixer.map(|m| m.commands(&u));
        let armed = self.armed && cmd.is_some();
        self.motors = match cmd {
            Some(c) if armed => c.commands,
            _ => [0.0; 4],
        };
        if armed && cmd.is_some_and(|c| c.clamped) {
            self.counters.clamped_steps = self.counters.clamped_steps.wrapping_add(1);
        }
        out.send(
            Peer::Simulator,
            &MavMessage::HIL_ACTUATOR_CONTROLS(hil::actuator_controls(s.time_us, &self.motors, self.armed)),
        )?;
        self.watch_ground_station(s.time_us, out)?;
        self.mission.tick(s.time_us, out)?;
        self.fly_mode(s.time_us, dt_s, out)?;
        self.telemetry(s.time_us, out)
    }

    /// A barometric altitude (`HIL_SENSOR`, flagged): fused as the height
    /// above home at most every [`BARO_PERIOD_US`], once the estimator has
    /// a position. Its first reading is referenced to the estimated height
    /// then (a barometer's altitude is above sea level, and drifts with the
    /// weather: what is fused is its change).
    fn on_baro(&mut self, t_us: u64, alt_m: f32) {
        let est_down_m = self.core.navigator().estimate().map(|e| e.pos_ned_m[2]);
        let Some(fix) = self.baro.fix(t_us, alt_m, est_down_m) else {
            return;
        };
        self.core.push_fix(&fix);
        self.counters.baro_fixes = self.counters.baro_fixes.wrapping_add(1);
    }

    /// A magnetometer reading (`HIL_SENSOR`, all three axes flagged): its
    /// tilt-compensated heading ([`hil::mag_heading_rad`], levelled with the
    /// estimated roll and pitch) fused at most every [`BARO_PERIOD_US`].
    /// The first reading is referenced to the estimated heading then, which
    /// removes the declination (no world magnetic model on board).
    fn on_mag(&mut self, t_us: u64, mag_frd: &Vector3<f32>) {
        let Some(est) = self.core.navigator().estimate() else {
            return;
        };
        let e = est.euler();
        let Some(psi_mag) = hil::mag_heading_rad(mag_frd, e[0], e[1]) else {
            return;
        };
        if !self.mag_due.due(t_us, BARO_PERIOD_US) {
            return;
        }
        let reference = *self.mag_ref_rad.get_or_insert(psi_mag - e[2]);
        let fix = Fix {
            yaw_rad: Some(fc_core::control::wrap_pi(psi_mag - reference)),
            yaw_sigma_rad: MAG_SIGMA_RAD,
            ..Fix::EMPTY
        };
        self.core.push_fix(&fix);
        self.counters.mag_fixes = self.counters.mag_fixes.wrapping_add(1);
    }

    fn on_state(&mut self, m: &HIL_STATE_QUATERNION_DATA) {
        if !hil::on_earth(m) {
            self.counters.states_refused = self.counters.states_refused.wrapping_add(1);
            return;
        }
        let home = *self.home.get_or_insert(Home::of(m));
        self.reported_ned_m = Some(home.ned_m(m.lat, m.lon, m.alt));
        let period_us = u64::from(self.core.settings().fix_period_ms) * 1000;
        if self.last_fix_us.is_some_and(|t| m.time_usec < t + period_us) {
            return;
        }
        match hil::fix_from_hil_state(m, &home, &StateFixSigmas::MOCAP_LIKE) {
            Ok(mut f) => {
                // A mocap gives position and heading, not velocity.
                f.vel_ned_mps = None;
                self.core.push_fix(&f);
                self.last_fix_us = Some(m.time_usec);
            }
            Err(_) => self.counters.states_refused = self.counters.states_refused.wrapping_add(1),
        }
    }

    fn on_command<S: MavSink>(&mut self, c: &Command, out: &mut S) -> Result<(), S::Error> {
        let p = &c.params;
        // The message a request asks for, sent after its acknowledgement.
        let mut then_send = None;
        let result = match c.command {
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if p[0] == 1.0 => match self.arm() {
                Ok(()) => {
                    self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("armed"))?;
                    MavResult::MAV_RESULT_ACCEPTED
                }
                Err(why) => {
                    self.say(
                        out,
                        MavSeverity::MAV_SEVERITY_WARNING,
                        format_args!("arming refused: {why}"),
                    )?;
                    MavResult::MAV_RESULT_TEMPORARILY_REJECTED
                }
            },
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if p[0] == 0.0 && self.in_air() && p[1] != FORCE => {
                self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    format_args!("disarm refused: in the air (force: 21196)"),
                )?;
                MavResult::MAV_RESULT_DENIED
            }
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if p[0] == 0.0 => {
                if self.armed {
                    self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("disarmed"))?;
                }
                self.disarm();
                MavResult::MAV_RESULT_ACCEPTED
            }
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => MavResult::MAV_RESULT_DENIED,
            MavCmd::MAV_CMD_NAV_TAKEOFF => self.mode_command(FlightMode::Takeoff, p[6], out)?,
            MavCmd::MAV_CMD_NAV_LAND => self.mode_command(FlightMode::Land, f32::NAN, out)?,
            MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH => self.mode_command(FlightMode::Return, f32::NAN, out)?,
            MavCmd::MAV_CMD_DO_SET_MODE => {
                // `as` saturates (NaN to 0): an absurd parameter names no mode.
                let base = p[0] as u8;
                let flags = MavModeFlag::from_bits_truncate(base);
                let custom = flags.contains(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED);
                let mode = if custom {
                    FlightMode::from_px4(p[1] as u8, p[2] as u8)
                } else {
                    FlightMode::from_base_mode(flags)
                };
                match mode {
                    Some(m) => self.mode_command(m, f32::NAN, out)?,
                    None if custom => {
                        self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            // As integers: f32's Display would link core's float formatting.
                            format_args!("mode {}/{} not flown here", p[1] as i32, p[2] as i32),
                        )?;
                        MavResult::MAV_RESULT_DENIED
                    }
                    None => {
                        self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            format_args!("base mode {base} not flown here"),
                        )?;
                        MavResult::MAV_RESULT_DENIED
                    }
                }
            }
            // The older requests, superseded by REQUEST_MESSAGE, are still
            // what some ground stations send.
            #[allow(deprecated)]
            MavCmd::MAV_CMD_REQUEST_MESSAGE
            | MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
            | MavCmd::MAV_CMD_GET_HOME_POSITION => {
                #[allow(deprecated)]
                let id = match c.command {
                    MavCmd::MAV_CMD_REQUEST_MESSAGE => p[0] as u32,
                    MavCmd::MAV_CMD_GET_HOME_POSITION => 242,
                    _ => AUTOPILOT_VERSION_ID,
                };
                match self.message(id, self.last_sensor_us.unwrap_or(0)) {
                    Some(m) => {
                        then_send = Some(m);
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    None => MavResult::MAV_RESULT_UNSUPPORTED,
                }
            }
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => {
                let (id, us) = (p[0] as u32, p[1]);
                match STREAMS.iter().position(|&(sid, _)| sid == id) {
                    Some(k) if us.is_finite() && us >= -1.0 => {
                        self.streams[k].0 = if us == -1.0 {
                            0
                        } else if us == 0.0 {
                            STREAMS[k].1
                        } else {
                            (us as u64).max(MIN_INTERVAL_US)
                        };
                        self.streams[k].1 = 0;
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    Some(_) => MavResult::MAV_RESULT_DENIED,
                    None => MavResult::MAV_RESULT_UNSUPPORTED,
                }
            }
            MavCmd::MAV_CMD_MISSION_START => self.mode_command(FlightMode::Mission, f32::NAN, out)?,
            _ => MavResult::MAV_RESULT_UNSUPPORTED,
        };
        if result != MavResult::MAV_RESULT_ACCEPTED {
            self.counters.commands_refused = self.counters.commands_refused.wrapping_add(1);
        }
        out.send(
            Peer::GroundStation,
            &MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                command: c.command,
                result,
            }),
        )?;
        match then_send {
            Some(m) => out.send(Peer::GroundStation, &m),
            None => Ok(()),
        }
    }

    /// A mode asked for (by `DO_SET_MODE` or its own command): entered, or
    /// refused with a `STATUSTEXT` saying why. `alt_amsl_m` is a takeoff's
    /// height above sea level (NaN: `MIS_TAKEOFF_ALT` above home).
    fn mode_command<S: MavSink>(
        &mut self,
        mode: FlightMode,
        alt_amsl_m: f32,
        out: &mut S,
    ) -> Result<MavResult, S::Error> {
        let t_us = self.last_sensor_us.unwrap_or(0);
        match self.set_mode(mode, t_us, alt_amsl_m) {
            Ok(()) => Ok(MavResult::MAV_RESULT_ACCEPTED),
            Err(why) => {
                self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    format_args!("{mode} refused: {why}"),
                )?;
                Ok(MavResult::MAV_RESULT_DENIED)
            }
        }
    }

    /// The flight mode.
    pub fn mode(&self) -> FlightMode {
        self.mode
    }

    /// The automatic modes' settings (PX4's parameters).
    pub fn nav_settings(&self) -> &NavSettings {
        &self.nav
    }

    /// Enters `mode` at `t_us` (see [`crate::modes`]).
    fn set_mode(&mut self, mode: FlightMode, t_us: u64, alt_amsl_m: f32) -> Result<(), &'static str> {
        let est = self.core.navigator().estimate();
        let here = est.map(|e| e.pos_ned_m);
        let yaw = est.map_or(0.0, |e| fc_core::quat_to_euler(&e.att)[2]);
        match mode {
            FlightMode::Position | FlightMode::Hold => {
                if let (true, Some(p)) = (self.armed, here) {
                    self.core.set_setpoint(&Setpoint::hold(p, yaw));
                }
            }
            FlightMode::Offboard => {
                let fresh = self
                    .offboard
                    .filter(|&(_, at)| t_us.saturating_sub(at) <= self.offboard_loss_us());
                let Some((sp, _)) = fresh else {
                    return Err("no set-points streaming");
                };
                if self.armed {
                    self.core.set_setpoint(&sp);
                }
            }
            FlightMode::Mission => {
                if self.mission.items().is_empty() {
                    return Err("no mission");
                }
                if !self.armed {
                    return Err("disarmed");
                }
                if usize::from(self.mission.current()) >= self.mission.items().len() {
                    self.mission.set_current(0);
                }
                self.mission_phase = None;
                self.mission_cruise_mps = None;
            }
            FlightMode::Takeoff | FlightMode::Land | FlightMode::Return => {
                if !self.armed {
                    return Err("disarmed");
                }
                let Some(p) = here else {
                    return Err("no position");
                };
                let ground = self.home_ned_m[2];
                let mut legs = Legs::new();
                let _ = match mode {
                    FlightMode::Takeoff => {
                        let above_origin = self.home.map_or(f32::NAN, |h| alt_amsl_m - h.alt_mm as f32 * 1e-3);
                        let up = if above_origin.is_finite() {
                            above_origin
                        } else {
                            self.nav.takeoff_alt_m - ground
                        };
                        legs.push_back((Vector3::new(p[0], p[1], -up), self.nav.climb_mps))
                    }
                    FlightMode::Land => legs.push_back((Vector3::new(p[0], p[1], ground), self.nav.land_mps)),
                    _ => {
                        // Return: up to RTL_RETURN_ALT (if lower), over home, down.
                        let cruise = p[2].min(ground - self.nav.rtl_alt_m);
                        let h = self.home_ned_m;
                        let _ = legs.push_back((Vector3::new(p[0], p[1], cruise), self.nav.climb_mps));
                        let _ = legs.push_back((Vector3::new(h[0], h[1], cruise), self.nav.cruise_mps));
                        legs.push_back((Vector3::new(h[0], h[1], ground), self.nav.land_mps))
                    }
                };
                let from = Reference::from(self.core.setpoint());
                if !self.route.start(t_us, &from, legs, self.core.setpoint().yaw_rad) {
                    return Err("goal out of range");
                }
            }
        }
        if mode != FlightMode::Mission {
            self.mission_phase = None;
        }
        self.mode = mode;
        Ok(())
    }

    fn offboard_loss_us(&self) -> u64 {
        (self.nav.offboard_loss_s * 1e6) as u64
    }

    /// Each step, what the mode flies: the automatic mode's route (a
    /// takeoff then holds; a return or a landing disarms on the ground),
    /// Offboard's loss of set-points (then Hold).
    fn fly_mode<S: MavSink>(&mut self, t_us: u64, dt_s: f32, out: &mut S) -> Result<(), S::Error> {
        if !self.armed {
            return Ok(());
        }
        match self.mode {
            FlightMode::Position => return self.fly_joystick(t_us, dt_s, out),
            FlightMode::Takeoff | FlightMode::Land | FlightMode::Return => {
                let Some((r, done)) = self.route.at(t_us) else {
                    return Ok(());
                };
                self.core.set_setpoint(&r.setpoint());
                if self.mode == FlightMode::Takeoff && done {
                    self.mode = FlightMode::Hold;
                    return self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("takeoff done: hold"));
                }
                // Landed (PX4's land detector, simplified): landing, on the
                // ground it armed on and not moving up or down.
                let landing = self.mode == FlightMode::Land || self.route_descending();
                let on_ground = self.core.navigator().estimate().is_some_and(|e| {
                    (e.pos_ned_m[2] - self.home_ned_m[2]).abs() < LANDED_M && e.vel_ned_mps[2].abs() < LANDED_MPS
                });
                if landing && on_ground {
                    self.disarm();
                    return self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("landed: disarmed"));
                }
            }
            FlightMode::Mission => return self.fly_mission(t_us, out),
            FlightMode::Offboard => {
                let lost = self
                    .offboard
                    .is_none_or(|(_, at)| t_us.saturating_sub(at) > self.offboard_loss_us());
                if lost {
                    let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                    return self.say(
                        out,
                        MavSeverity::MAV_SEVERITY_WARNING,
                        format_args!("offboard set-points lost: hold"),
                    );
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Position mode's step: the joystick moves the set-point
    /// ([`joystick_velocity`]); a joystick heard and then silent for
    /// `COM_RC_LOSS_T` is lost: Land, as for a lost ground station.
    fn fly_joystick<S: MavSink>(&mut self, t_us: u64, dt_s: f32, out: &mut S) -> Result<(), S::Error> {
        let Some(([x, y, z, r], at)) = self.manual else {
            return Ok(());
        };
        if t_us.saturating_sub(at) as f32 * 1e-6 > self.nav.manual_loss_s {
            self.manual = None;
            if self.set_mode(FlightMode::Land, t_us, f32::NAN).is_ok() {
                return self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_CRITICAL,
                    format_args!("joystick lost: landing"),
                );
            }
            return Ok(());
        }
        let mut sp = *self.core.setpoint();
        let (v, yaw_rate) = joystick_velocity(&self.nav, x, y, z, r, sp.yaw_rad);
        let dt = dt_s.clamp(0.0, 0.1);
        sp.pos_ned_m += v * dt;
        // Not below the ground it armed on (throttle down on the ground).
        sp.pos_ned_m[2] = sp.pos_ned_m[2].min(self.home_ned_m[2]);
        sp.yaw_rad = fc_core::control::wrap_pi(sp.yaw_rad + yaw_rate * dt);
        sp.vel_ned_mps = v;
        sp.acc_ned_mps2 = Vector3::zeros();
        sp.yaw_rate_radps = yaw_rate;
        self.core.set_setpoint(&sp);
        Ok(())
    }

    /// Mission mode's step: the item flown (its route, its hold), then the
    /// next; Land and Return items hand over to those modes; after the
    /// last, Hold. At most every item once per step (a speed change takes
    /// none of the vehicle's time).
    fn fly_mission<S: MavSink>(&mut self, t_us: u64, out: &mut S) -> Result<(), S::Error> {
        for _ in 0..=MISSION_CAPACITY {
            match self.mission_phase {
                None => {
                    let seq = self.mission.current();
                    let Some(item) = self.mission.items().get(usize::from(seq)).copied() else {
                        let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                        return self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("mission done: hold"));
                    };
                    let origin = self.home.unwrap_or_default();
                    let sp = *self.core.setpoint();
                    let from = Reference::from(&sp);
                    let mut legs = Legs::new();
                    let (goal, accept_m, hold_s) = match item.step(&origin, self.home_ned_m[2]) {
                        Ok(Step::Goto { ned, hold_s, accept_m }) => {
                            let cruise = self.mission_cruise_mps.unwrap_or(self.nav.cruise_mps);
                            let _ = legs.push_back((ned, cruise));
                            (ned, accept_m, hold_s)
                        }
                        Ok(Step::Takeoff { up_m }) => {
                            let goal = Vector3::new(sp.pos_ned_m[0], sp.pos_ned_m[1], self.home_ned_m[2] - up_m);
                            let _ = legs.push_back((goal, self.nav.climb_mps));
                            (goal, 0.0, 0.0)
                        }
                        Ok(Step::Delay { s }) => {
                            self.mission_phase = Some(MissionPhase::Holding {
                                seq,
                                until_us: t_us.saturating_add((s * 1e6) as u64),
                            });
                            return Ok(());
                        }
                        Ok(Step::Speed { mps }) => {
                            self.mission_cruise_mps = Some(mps);
                            self.mission_reached(seq, out)?;
                            continue;
                        }
                        Ok(Step::Land) | Ok(Step::Return) => {
                            self.mission_reached(seq, out)?;
                            let next = if item.command == MavCmd::MAV_CMD_NAV_LAND {
                                FlightMode::Land
                            } else {
                                FlightMode::Return
                            };
                            let _ = self.set_mode(next, t_us, f32::NAN);
                            return Ok(());
                        }
                        Err(_) => {
                            let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                            return self.say(
                                out,
                                MavSeverity::MAV_SEVERITY_WARNING,
                                format_args!("mission item {seq} cannot be flown: hold"),
                            );
                        }
                    };
                    if !self.route.start(t_us, &from, legs, sp.yaw_rad) {
                        let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                        return self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            format_args!("mission item {seq} out of range: hold"),
                        );
                    }
                    self.mission_phase = Some(MissionPhase::Flying {
                        seq,
                        goal,
                        accept_m,
                        hold_s,
                    });
                    return Ok(());
                }
                Some(MissionPhase::Flying {
                    seq,
                    goal,
                    accept_m,
                    hold_s,
                }) => {
                    let Some((r, done)) = self.route.at(t_us) else {
                        return Ok(());
                    };
                    self.core.set_setpoint(&r.setpoint());
                    let accept = if accept_m > 0.0 { accept_m } else { self.nav.acc_rad_m };
                    let near = self
                        .core
                        .navigator()
                        .estimate()
                        .is_some_and(|e| (e.pos_ned_m - goal).norm() <= accept);
                    if !(done && near) {
                        return Ok(());
                    }
                    if hold_s > 0.0 {
                        self.mission_phase = Some(MissionPhase::Holding {
                            seq,
                            until_us: t_us.saturating_add((hold_s * 1e6) as u64),
                        });
                        return Ok(());
                    }
                    self.mission_reached(seq, out)?;
                }
                Some(MissionPhase::Holding { seq, until_us }) => {
                    if t_us < until_us {
                        return Ok(());
                    }
                    self.mission_reached(seq, out)?;
                }
            }
        }
        Ok(())
    }

    /// Item `seq` done: `MISSION_ITEM_REACHED`, the next one current.
    fn mission_reached<S: MavSink>(&mut self, seq: u16, out: &mut S) -> Result<(), S::Error> {
        self.mission_phase = None;
        out.send(
            Peer::GroundStation,
            &MavMessage::MISSION_ITEM_REACHED(MISSION_ITEM_REACHED_DATA { seq }),
        )?;
        self.mission.set_current(seq.saturating_add(1));
        out.send(Peer::GroundStation, &self.mission.current_message())
    }

    /// The ground-station failsafe (`FS_GCS_MS`): armed, a ground station
    /// was heard, and it has been silent that long → Land (where it is,
    /// then disarmed on the ground). Set-points no longer count; a
    /// heartbeat again does not cancel it (as PX4's data-link loss).
    fn watch_ground_station<S: MavSink>(&mut self, now_us: u64, out: &mut S) -> Result<(), S::Error> {
        let limit_us = u64::from(self.core.settings().gcs_loss_ms) * 1000;
        let lost = self.gcs_seen_us.is_some_and(|t| now_us.saturating_sub(t) > limit_us);
        if self.armed
            && self.mode != FlightMode::Land
            && limit_us > 0
            && lost
            && self.set_mode(FlightMode::Land, now_us, f32::NAN).is_ok()
        {
            self.gcs_seen_us = None;
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_CRITICAL,
                format_args!("ground station lost: landing"),
            )?;
        }
        Ok(())
    }

    /// Armed and more than [`IN_AIR_M`] above where it armed (estimated):
    /// disarming would drop it.
    fn in_air(&self) -> bool {
        let down = self.core.navigator().estimate().map(|e| e.pos_ned_m[2]);
        self.armed && down.is_some_and(|d| d < self.home_ned_m[2] - IN_AIR_M)
    }

    /// PX4's landed state: on the ground, taking off, in the air, landing.
    pub fn landed_state(&self) -> MavLandedState {
        let landing = self.mode == FlightMode::Land || self.route_descending();
        match (self.armed, self.in_air()) {
            (false, _) => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
            (true, _) if self.mode == FlightMode::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
            (true, true) if landing => MavLandedState::MAV_LANDED_STATE_LANDING,
            (true, true) => MavLandedState::MAV_LANDED_STATE_IN_AIR,
            (true, false) => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
        }
    }

    /// A return's last leg (straight down over home) is under way.
    fn route_descending(&self) -> bool {
        self.mode == FlightMode::Return && self.route.on_last_leg()
    }

    fn disarm(&mut self) {
        self.armed = false;
        if !matches!(self.mode, FlightMode::Position | FlightMode::Offboard) {
            self.mode = FlightMode::Hold;
        }
    }

    /// Arms if the estimator navigates; the controller is designed afresh.
    /// Where it arms is home; it holds there (or, in Offboard, flies the
    /// streamed set-point; an automatic mode becomes Hold).
    fn arm(&mut self) -> Result<(), &'static str> {
        if self.armed {
            return Ok(());
        }
        if self.mixer.is_none() {
            return Err("not started");
        }
        let est = match (self.core.navigator().mode(), self.core.navigator().estimate()) {
            (NavMode::Navigating, Some(e)) => e,
            (NavMode::Aligning, _) => return Err("estimator aligning"),
            _ => return Err("estimator failsafe"),
        };
        self.core
            .try_select(self.core.settings().controller)
            .map_err(|_| "controller design failed")?;
        let yaw = fc_core::quat_to_euler(&est.att)[2];
        match (self.mode, self.offboard) {
            (FlightMode::Offboard, Some((sp, _))) => {
                self.core.set_setpoint(&sp);
            }
            (mode, _) => {
                self.core.set_setpoint(&Setpoint::hold(est.pos_ned_m, yaw));
                if mode != FlightMode::Position {
                    self.mode = FlightMode::Hold;
                }
            }
        }
        self.home_ned_m = est.pos_ned_m;
        self.armed = true;
        Ok(())
    }

    fn on_setpoint<S: MavSink>(&mut self, m: &SET_POSITION_TARGET_LOCAL_NED_DATA, out: &mut S) -> Result<(), S::Error> {
        if !self.for_me(m.target_system) {
            self.counters.ignored = self.counters.ignored.wrapping_add(1);
            return Ok(());
        }
        // The frame and mask here; the values (finite, within range) by the
        // flight loop, as for every protocol. Kept for Offboard; flown only
        // in Offboard, as PX4 does. A masked heading keeps the one held:
        // armed, the set-point's; on the ground, the vehicle's own, so a
        // take-off in Offboard keeps the heading it has.
        let held_yaw = match (self.armed, self.core.navigator().estimate()) {
            (false, Some(e)) => fc_core::quat_to_euler(&e.att)[2],
            _ => self.core.setpoint().yaw_rad,
        };
        let sp = setpoint_from_target(m, held_yaw).filter(|sp| sp.is_valid());
        match sp {
            Some(mut sp) => {
                let last = self.offboard_acc.take();
                if !acc_masked(m.type_mask) {
                    sp.jerk_ned_mps3 = streamed_jerk(last, sp.acc_ned_mps2, m.time_boot_ms);
                    self.offboard_acc = Some((sp.acc_ned_mps2, m.time_boot_ms));
                }
                self.offboard = Some((sp, self.last_sensor_us.unwrap_or(0)));
                if self.mode == FlightMode::Offboard && self.armed {
                    self.core.set_setpoint(&sp);
                }
                Ok(())
            }
            None => {
                self.counters.setpoints_refused = self.counters.setpoints_refused.wrapping_add(1);
                self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    format_args!("set-point refused: LOCAL_NED, position, finite"),
                )
            }
        }
    }

    fn on_param_set<S: MavSink>(&mut self, m: &PARAM_SET_DATA, out: &mut S) -> Result<(), S::Error> {
        let Some(i) = param_index_of(&m.param_id[..]) else {
            self.counters.params_refused = self.counters.params_refused.wrapping_add(1);
            return self.status(
                out,
                MavSeverity::MAV_SEVERITY_WARNING,
                &m.param_id[..],
                Refusal::Unknown,
            );
        };
        let r = match i.checked_sub(PARAMS.len()) {
            Some(k) => self.nav.set(k, m.param_value),
            None => self.apply(i, m.param_value),
        };
        if let Err(why) = r {
            self.counters.params_refused = self.counters.params_refused.wrapping_add(1);
            let id = param_id(i);
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_WARNING,
                format_args!("{id}={} refused: {why}", params::Num(m.param_value)),
            )?;
        } else if let Some(Err(e)) = out.storage().map(|st| st.set_param(i as u16, m.param_value)) {
            // Taken for this flight, but not kept: say so.
            let id = param_id(i);
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_ERROR,
                format_args!("{id} not stored: {e}"),
            )?;
        }
        // The value in force, changed or not, as the protocol asks.
        self.send_param(i, out)
    }

    /// Takes the automatic modes' parameters ([`NAV_PARAMS`]) stored in `p`
    /// (the flight parameters are loaded into the boot settings with
    /// [`fc_storage::load_settings`]); a stored value out of range is left
    /// out. The values taken and refused, or why the store could not be read.
    pub fn restore_nav(&mut self, p: &mut dyn fc_storage::Persist) -> Result<(u16, u16), fc_storage::StoreError> {
        let (mut taken, mut refused) = (0, 0);
        for k in 0..NAV_PARAMS.len() {
            if let Some(v) = p.param((PARAMS.len() + k) as u16)? {
                match self.nav.set(k, v) {
                    Ok(()) => taken += 1,
                    Err(_) => refused += 1,
                }
            }
        }
        Ok((taken, refused))
    }

    /// Sets parameter `index` to `value`: checked, and applied to the
    /// controller (re-designed while disarmed), the mixer and the failsafe.
    pub fn apply(&mut self, index: usize, value: f32) -> Result<(), Refusal> {
        self.core.apply_param(index, value, !self.armed)?;
        self.mixer = Some(self.core.settings().mixer()?);
        Ok(())
    }

    fn send_param<S: MavSink>(&self, index: usize, out: &mut S) -> Result<(), S::Error> {
        let value = match (
            PARAMS.get(index),
            index.checked_sub(PARAMS.len()).and_then(|k| NAV_PARAMS.get(k)),
        ) {
            (Some(p), _) => (p.get)(self.core.settings()),
            (None, Some(p)) => (p.get)(&self.nav),
            (None, None) => return Ok(()),
        };
        out.send(
            Peer::GroundStation,
            &MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                param_value: value,
                param_count: PARAM_COUNT as u16,
                param_index: index as u16,
                param_id: param_id(index).into(),
                param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
            }),
        )
    }

    /// A `STATUSTEXT` naming parameter `id` and why it was refused.
    fn status<S: MavSink>(&self, out: &mut S, sev: MavSeverity, id: &[u8], why: Refusal) -> Result<(), S::Error> {
        let len = id.iter().position(|&b| b == 0).unwrap_or(id.len());
        let name = core::str::from_utf8(&id[..len]).unwrap_or("?");
        self.say(out, sev, format_args!("{name}: {why}"))
    }

    /// Sends a `STATUSTEXT` (cut at 50 characters).
    fn say<S: MavSink>(&self, out: &mut S, severity: MavSeverity, text: core::fmt::Arguments) -> Result<(), S::Error> {
        let mut t = Text { buf: [0; 50], len: 0 };
        let _ = core::fmt::write(&mut t, text);
        out.send(
            Peer::GroundStation,
            &MavMessage::STATUSTEXT(STATUSTEXT_DATA {
                severity,
                text: t.buf.into(),
            }),
        )
    }

    /// Sends the telemetry due at simulated time `t_us` ([`STREAMS`], at
    /// their intervals).
    fn telemetry<S: MavSink>(&mut self, t_us: u64, out: &mut S) -> Result<(), S::Error> {
        for (k, &(id, _)) in STREAMS.iter().enumerate() {
            let (interval, next) = self.streams[k];
            if interval == 0 || t_us < next {
                continue;
            }
            self.streams[k].1 = t_us.saturating_add(interval);
            if let Some(m) = self.message(id, t_us) {
                if id == 0 {
                    out.send(Peer::Simulator, &m)?;
                }
                out.send(Peer::GroundStation, &m)?;
            }
        }
        Ok(())
    }

    /// Message `id` as of `t_us`, if this vehicle sends it (and has what it
    /// carries: an estimate, a home).
    fn message(&self, id: u32, t_us: u64) -> Option<MavMessage> {
        let est = self.core.navigator().estimate();
        let time_boot_ms = boot_ms(t_us);
        Some(match id {
            0 => MavMessage::HEARTBEAT(hil::heartbeat(self.armed, self.mode.custom_mode())),
            1 => MavMessage::SYS_STATUS(self.sys_status()),
            30 => {
                let e = est?;
                let rpy = fc_core::quat_to_euler(&e.att);
                MavMessage::ATTITUDE(ATTITUDE_DATA {
                    time_boot_ms,
                    roll: rpy[0],
                    pitch: rpy[1],
                    yaw: rpy[2],
                    rollspeed: e.rates_frd_radps[0],
                    pitchspeed: e.rates_frd_radps[1],
                    yawspeed: e.rates_frd_radps[2],
                })
            }
            31 => {
                let e = est?;
                MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
                    time_boot_ms,
                    q1: e.att[0],
                    q2: e.att[1],
                    q3: e.att[2],
                    q4: e.att[3],
                    rollspeed: e.rates_frd_radps[0],
                    pitchspeed: e.rates_frd_radps[1],
                    yawspeed: e.rates_frd_radps[2],
                })
            }
            32 => {
                let e = est?;
                MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
                    time_boot_ms,
                    x: e.pos_ned_m[0],
                    y: e.pos_ned_m[1],
                    z: e.pos_ned_m[2],
                    vx: e.vel_ned_mps[0],
                    vy: e.vel_ned_mps[1],
                    vz: e.vel_ned_mps[2],
                })
            }
            33 => {
                let (e, h) = (est?, self.home?);
                let (lat, lon, alt) = h.geodetic(&e.pos_ned_m.cast());
                let cm = |v: f32| (v * 100.0).clamp(-32_767.0, 32_767.0) as i16;
                let yaw_deg = fc_core::quat_to_euler(&e.att)[2].to_degrees();
                MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
                    time_boot_ms,
                    lat,
                    lon,
                    alt,
                    relative_alt: ((self.home_ned_m[2] - e.pos_ned_m[2]) * 1e3) as i32,
                    vx: cm(e.vel_ned_mps[0]),
                    vy: cm(e.vel_ned_mps[1]),
                    vz: cm(e.vel_ned_mps[2]),
                    hdg: (libm::fmodf(yaw_deg + 360.0, 360.0) * 100.0) as u16 % 36_000,
                })
            }
            242 => {
                let h = self.home?;
                let (latitude, longitude, altitude) = h.geodetic(&self.home_ned_m.cast());
                MavMessage::HOME_POSITION(HOME_POSITION_DATA {
                    latitude,
                    longitude,
                    altitude,
                    x: self.home_ned_m[0],
                    y: self.home_ned_m[1],
                    z: self.home_ned_m[2],
                    q: [1.0, 0.0, 0.0, 0.0],
                    approach_x: 0.0,
                    approach_y: 0.0,
                    approach_z: 0.0,
                })
            }
            245 => MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
                vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
                landed_state: self.landed_state(),
            }),
            42 => self.mission.current_message(),
            230 => MavMessage::ESTIMATOR_STATUS(self.estimator_status(t_us)),
            AUTOPILOT_VERSION_ID => MavMessage::AUTOPILOT_VERSION(autopilot_version(self.system_id)),
            _ => return None,
        })
    }

    /// `ESTIMATOR_STATUS`: what the estimator gives (attitude, velocity,
    /// position about the origin and, about the simulator's origin, a
    /// global one) while it navigates; its 1σ position accuracy; the latest
    /// fixes' innovation test ratios as PX4 gives them (the vertical one
    /// the larger of the position's and the barometer's, the heading's as
    /// `mag_ratio`; no height-above-ground or airspeed source: 0).
    fn estimator_status(&self, t_us: u64) -> ESTIMATOR_STATUS_DATA {
        use EstimatorStatusFlags as F;
        let nav = self.core.navigator();
        let sig = nav.estimator().sigmas();
        let navigating = nav.mode() == NavMode::Navigating;
        let mut flags = F::empty();
        if navigating {
            flags = F::ESTIMATOR_ATTITUDE
                | F::ESTIMATOR_VELOCITY_HORIZ
                | F::ESTIMATOR_VELOCITY_VERT
                | F::ESTIMATOR_POS_HORIZ_REL
                | F::ESTIMATOR_POS_VERT_ABS
                | F::ESTIMATOR_PRED_POS_HORIZ_REL;
            if self.home.is_some() {
                flags |= F::ESTIMATOR_POS_HORIZ_ABS | F::ESTIMATOR_PRED_POS_HORIZ_ABS;
            }
        }
        // PX4 sends the square roots of the estimator's ratios.
        let r = nav.estimator().test_ratios();
        ESTIMATOR_STATUS_DATA {
            time_usec: t_us,
            vel_ratio: libm::sqrtf(r.vel),
            pos_horiz_ratio: libm::sqrtf(r.pos_horiz),
            pos_vert_ratio: libm::sqrtf(r.pos_vert.max(r.alt)),
            mag_ratio: libm::sqrtf(r.yaw),
            hagl_ratio: 0.0,
            tas_ratio: 0.0,
            pos_horiz_accuracy: sig[0].max(sig[1]),
            pos_vert_accuracy: sig[2],
            flags,
        }
    }

    fn sys_status(&self) -> SYS_STATUS_DATA {
        use MavSysStatusSensor as S;
        // The position source: the simulator's state as an external
        // (vision-like) position, and a global one about its origin (home).
        let mut present = S::MAV_SYS_STATUS_SENSOR_3D_GYRO
            | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
            | S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
            | S::MAV_SYS_STATUS_SENSOR_VISION_POSITION
            | S::MAV_SYS_STATUS_PREARM_CHECK;
        if self.home.is_some() {
            present |= S::MAV_SYS_STATUS_SENSOR_GPS;
        }
        let mut healthy = present;
        let navigating = self.core.navigator().mode() == NavMode::Navigating && !self.core.failsafe();
        if !navigating {
            healthy.remove(
                S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
                    | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
                    | S::MAV_SYS_STATUS_SENSOR_VISION_POSITION
                    | S::MAV_SYS_STATUS_SENSOR_GPS
                    | S::MAV_SYS_STATUS_PREARM_CHECK,
            );
        }
        if self.mixer.is_none() {
            healthy.remove(S::MAV_SYS_STATUS_PREARM_CHECK);
        }
        // There is no fence, so none is breached: a clear health bit reads
        // as a breach to ground stations that watch it (MAVProxy's fence
        // module prints "fence breach").
        healthy |= S::MAV_SYS_STATUS_GEOFENCE;
        // Load: the last step's time against a 1 kHz step, per mille.
        let per_step = u64::from(self.cycles.1) / 1000;
        let load = (u64::from(self.cycles.0) * 1000).checked_div(per_step).unwrap_or(0);
        SYS_STATUS_DATA {
            onboard_control_sensors_present: present,
            onboard_control_sensors_enabled: present,
            onboard_control_sensors_health: healthy,
            load: load.min(1000) as u16,
            // No battery is measured (no board input, and a simulator over
            // PX4's HIL interface sends none): unknown, as MAVLink spells it,
            // rather than a model passed off as a measurement.
            voltage_battery: u16::MAX,
            current_battery: -1,
            drop_rate_comm: 0,
            errors_comm: self.link_errors.min(u32::from(u16::MAX)) as u16,
            errors_count1: self.counters.sensors_refused.min(u32::from(u16::MAX)) as u16,
            errors_count2: self.counters.params_refused.min(u32::from(u16::MAX)) as u16,
            errors_count3: self.counters.commands_refused.min(u32::from(u16::MAX)) as u16,
            errors_count4: self.core.counters().invalid_values.min(u32::from(u16::MAX)) as u16,
            battery_remaining: -1,
        }
    }
}

/// `AUTOPILOT_VERSION`: the capabilities that are true of this vehicle.
// PARAM_FLOAT is deprecated for PARAM_ENCODE_C_CAST; every parameter here
// is a REAL32, so both are true, and older clients read PARAM_FLOAT.
#[allow(deprecated)]
pub fn autopilot_version(system_id: u8) -> AUTOPILOT_VERSION_DATA {
    use MavProtocolCapability as C;
    AUTOPILOT_VERSION_DATA {
        capabilities: C::MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | C::MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | C::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
            | C::MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | C::MAV_PROTOCOL_CAPABILITY_MISSION_INT
            | C::MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED,
        uid: u64::from(system_id),
        flight_sw_version: FLIGHT_SW_VERSION,
        middleware_sw_version: 0,
        os_sw_version: 0,
        board_version: 0,
        vendor_id: 0,
        product_id: 0,
        flight_custom_version: [0; 8],
        middleware_custom_version: [0; 8],
        os_custom_version: [0; 8],
    }
}

/// The longest gap between two streamed accelerations that still gives a
/// jerk, ms (an Offboard stream comes at 10–50 Hz; PX4 leaves Offboard
/// after 1 s without one).
pub const JERK_GAP_MAX_MS: u32 = 100;

/// The largest jerk taken from a stream, m/s³ per axis: a change of
/// acceleration steeper than this is a new set-point, not a trajectory's
/// slope (a 1 m, 6 s figure-8 asks for 4.6).
pub const JERK_MAX_MPS3: f32 = 50.0;

/// The jerk feed-forward of a streamed trajectory, m/s³ NED:
/// `SET_POSITION_TARGET_LOCAL_NED` carries position, velocity and
/// acceleration but no jerk, and without it the controllers fly a moving
/// reference with no attitude-rate feed-forward (a figure-8's error grows
/// tenfold). The slope of the acceleration between the `last` streamed
/// one and `acc`, over the sender's clock (`time_boot_ms`); zero when
/// there is no last one, the gap is not in (0, [`JERK_GAP_MAX_MS`]] ms, or
/// the slope is steeper than [`JERK_MAX_MPS3`] on an axis (a step).
pub fn streamed_jerk(last: Option<(Vector3<f32>, u32)>, acc: Vector3<f32>, t_ms: u32) -> Vector3<f32> {
    let Some((a0, t0)) = last else {
        return Vector3::zeros();
    };
    let gap = t_ms.wrapping_sub(t0);
    if gap == 0 || gap > JERK_GAP_MAX_MS {
        return Vector3::zeros();
    }
    let j = (acc - a0) / (gap as f32 * 1e-3);
    if j.iter().all(|v| v.is_finite() && v.abs() <= JERK_MAX_MPS3) {
        j
    } else {
        Vector3::zeros()
    }
}

/// Whether a `SET_POSITION_TARGET_LOCAL_NED` masks its acceleration (any
/// axis).
fn acc_masked(mask: PositionTargetTypemask) -> bool {
    use PositionTargetTypemask as T;
    mask.intersects(
        T::POSITION_TARGET_TYPEMASK_AX_IGNORE
            | T::POSITION_TARGET_TYPEMASK_AY_IGNORE
            | T::POSITION_TARGET_TYPEMASK_AZ_IGNORE,
    )
}

/// `SET_POSITION_TARGET_LOCAL_NED` as a set-point: `None` unless the frame
/// is `MAV_FRAME_LOCAL_NED` and the position is given. A masked yaw keeps
/// `yaw_rad`. The values are not checked here:
/// [`fc_loop::Loop::set_setpoint`] refuses what is not finite or in range.
pub fn setpoint_from_target(m: &SET_POSITION_TARGET_LOCAL_NED_DATA, yaw_rad: f32) -> Option<Setpoint<f32>> {
    use PositionTargetTypemask as T;
    let mask = m.type_mask;
    let pos_masked = T::POSITION_TARGET_TYPEMASK_X_IGNORE
        | T::POSITION_TARGET_TYPEMASK_Y_IGNORE
        | T::POSITION_TARGET_TYPEMASK_Z_IGNORE;
    if m.coordinate_frame != MavFrame::MAV_FRAME_LOCAL_NED
        || mask.intersects(pos_masked)
        || mask.contains(T::POSITION_TARGET_TYPEMASK_FORCE_SET)
    {
        return None;
    }
    let vel_masked = mask.intersects(
        T::POSITION_TARGET_TYPEMASK_VX_IGNORE
            | T::POSITION_TARGET_TYPEMASK_VY_IGNORE
            | T::POSITION_TARGET_TYPEMASK_VZ_IGNORE,
    );
    let yaw = if mask.contains(T::POSITION_TARGET_TYPEMASK_YAW_IGNORE) {
        yaw_rad
    } else {
        m.yaw
    };
    let mut sp = Setpoint::hold(Vector3::new(m.x, m.y, m.z), yaw);
    if !vel_masked {
        sp.vel_ned_mps = Vector3::new(m.vx, m.vy, m.vz);
    }
    if !acc_masked(mask) {
        sp.acc_ned_mps2 = Vector3::new(m.afx, m.afy, m.afz);
    }
    if !mask.contains(T::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE) {
        sp.yaw_rate_radps = m.yaw_rate;
    }
    Some(sp)
}

#[cfg(test)]
#[path = "vehicle_tests.rs"]
mod tests;
