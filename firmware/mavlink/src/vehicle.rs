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
/// `param2` of a disarm that is obeyed in the air too (MAVLink's magic number).
const FORCE: f32 = 21196.0;

/// Telemetry rates, Hz of simulated time.
const HEARTBEAT_HZ: u64 = 1;
const SYS_STATUS_HZ: u64 = 2;
const ATTITUDE_HZ: u64 = 50;
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
    /// Where it armed (estimated), down, m.
    armed_down_m: f32,
    /// Simulated time of the last ground-station `HEARTBEAT`, µs.
    gcs_seen_us: Option<u64>,
    /// Landing because the ground station was lost.
    landing: bool,
    /// A set-point arrived since boot (arming then keeps it).
    setpoint_given: bool,
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
    /// Next telemetry times, µs: heartbeat, status, attitude/position.
    next_us: [u64; 3],
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
            armed_down_m: 0.0,
            gcs_seen_us: None,
            landing: false,
            setpoint_given: false,
            home: None,
            last_fix_us: None,
            baro: Barometer::new(),
            mag_ref_rad: None,
            mag_due: Schedule::new(),
            last_sensor_us: None,
            seq: 0,
            motors: [0.0; 4],
            cycles: (0, 1),
            next_us: [0; 3],
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
            MavMessage::COMMAND_LONG(m) => self.on_command(m, out),
            MavMessage::SET_POSITION_TARGET_LOCAL_NED(m) => self.on_setpoint(m, out),
            MavMessage::PARAM_REQUEST_LIST(m) if self.for_me(m.target_system) => {
                for i in 0..PARAMS.len() {
                    self.send_param(i, out)?;
                }
                Ok(())
            }
            MavMessage::PARAM_REQUEST_READ(m) if self.for_me(m.target_system) => {
                let index = if m.param_index >= 0 {
                    Some(m.param_index as usize).filter(|&i| i < PARAMS.len())
                } else {
                    params::index_of(&m.param_id[..])
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
            self.next_us = [s.time_us; 3];
        }
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

    fn on_command<S: MavSink>(&mut self, m: &COMMAND_LONG_DATA, out: &mut S) -> Result<(), S::Error> {
        if !self.for_me(m.target_system) {
            self.counters.ignored = self.counters.ignored.wrapping_add(1);
            return Ok(());
        }
        let result = match m.command {
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if m.param1 == 1.0 => match self.arm() {
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
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if m.param1 == 0.0 && self.in_air() && m.param2 != FORCE => {
                self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    format_args!("disarm refused: in the air (force: 21196)"),
                )?;
                MavResult::MAV_RESULT_DENIED
            }
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if m.param1 == 0.0 => {
                if self.armed {
                    self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("disarmed"))?;
                }
                self.armed = false;
                MavResult::MAV_RESULT_ACCEPTED
            }
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => MavResult::MAV_RESULT_DENIED,
            _ => MavResult::MAV_RESULT_UNSUPPORTED,
        };
        if result != MavResult::MAV_RESULT_ACCEPTED {
            self.counters.commands_refused = self.counters.commands_refused.wrapping_add(1);
        }
        out.send(
            Peer::GroundStation,
            &MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                command: m.command,
                result,
            }),
        )
    }

    /// The ground-station failsafe (`FS_GCS_MS`): armed, a ground station
    /// was heard, and it has been silent that long → land where it is: the
    /// set-point drops to the height it armed at, and once there (within
    /// [`LANDED_M`]) it disarms. Set-points no longer count while landing;
    /// a heartbeat again does not cancel it (as PX4's data-link loss).
    fn watch_ground_station<S: MavSink>(&mut self, now_us: u64, out: &mut S) -> Result<(), S::Error> {
        let limit_us = u64::from(self.core.settings().gcs_loss_ms) * 1000;
        let Some(est) = self.core.navigator().estimate() else {
            return Ok(());
        };
        let lost = self.gcs_seen_us.is_some_and(|t| now_us.saturating_sub(t) > limit_us);
        if self.armed && !self.landing && limit_us > 0 && lost {
            self.landing = true;
            let yaw = fc_core::quat_to_euler(&est.att)[2];
            let ground = Vector3::new(est.pos_ned_m[0], est.pos_ned_m[1], self.armed_down_m);
            self.core.set_setpoint(&Setpoint::hold(ground, yaw));
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_CRITICAL,
                format_args!("ground station lost: landing"),
            )?;
        }
        if self.armed && self.landing && (est.pos_ned_m[2] - self.armed_down_m).abs() < LANDED_M {
            self.armed = false;
            self.landing = false;
            self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("landed: disarmed"))?;
        }
        Ok(())
    }

    /// Armed and more than [`IN_AIR_M`] above where it armed (estimated):
    /// disarming would drop it.
    fn in_air(&self) -> bool {
        let down = self.core.navigator().estimate().map(|e| e.pos_ned_m[2]);
        self.armed && down.is_some_and(|d| d < self.armed_down_m - IN_AIR_M)
    }

    /// Arms if the estimator navigates; the controller is designed afresh.
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
        if !self.setpoint_given {
            let yaw = fc_core::quat_to_euler(&est.att)[2];
            self.core.set_setpoint(&Setpoint::hold(est.pos_ned_m, yaw));
        }
        self.armed_down_m = est.pos_ned_m[2];
        self.landing = false;
        self.armed = true;
        Ok(())
    }

    fn on_setpoint<S: MavSink>(&mut self, m: &SET_POSITION_TARGET_LOCAL_NED_DATA, out: &mut S) -> Result<(), S::Error> {
        if !self.for_me(m.target_system) {
            self.counters.ignored = self.counters.ignored.wrapping_add(1);
            return Ok(());
        }
        // The frame and mask here; the values (finite, within range) by the
        // flight loop, as for every protocol.
        let accepted = match setpoint_from_target(m, self.core.setpoint().yaw_rad) {
            Some(_) if self.landing => return Ok(()),
            Some(sp) => self.core.set_setpoint(&sp),
            None => false,
        };
        if accepted {
            self.setpoint_given = true;
            return Ok(());
        }
        self.counters.setpoints_refused = self.counters.setpoints_refused.wrapping_add(1);
        self.say(
            out,
            MavSeverity::MAV_SEVERITY_WARNING,
            format_args!("set-point refused: LOCAL_NED, position, finite"),
        )
    }

    fn on_param_set<S: MavSink>(&mut self, m: &PARAM_SET_DATA, out: &mut S) -> Result<(), S::Error> {
        let Some(i) = params::index_of(&m.param_id[..]) else {
            self.counters.params_refused = self.counters.params_refused.wrapping_add(1);
            return self.status(
                out,
                MavSeverity::MAV_SEVERITY_WARNING,
                &m.param_id[..],
                Refusal::Unknown,
            );
        };
        if let Err(why) = self.apply(i, m.param_value) {
            self.counters.params_refused = self.counters.params_refused.wrapping_add(1);
            let id = PARAMS[i].id;
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_WARNING,
                format_args!("{id}={} refused: {why}", params::Num(m.param_value)),
            )?;
        }
        // The value in force, changed or not, as the protocol asks.
        self.send_param(i, out)
    }

    /// Sets parameter `index` to `value`: checked, and applied to the
    /// controller (re-designed while disarmed), the mixer and the failsafe.
    pub fn apply(&mut self, index: usize, value: f32) -> Result<(), Refusal> {
        self.core.apply_param(index, value, !self.armed)?;
        self.mixer = Some(self.core.settings().mixer()?);
        Ok(())
    }

    fn send_param<S: MavSink>(&self, index: usize, out: &mut S) -> Result<(), S::Error> {
        let p = &PARAMS[index];
        out.send(
            Peer::GroundStation,
            &MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                param_value: (p.get)(self.core.settings()),
                param_count: PARAMS.len() as u16,
                param_index: index as u16,
                param_id: p.id.into(),
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

    /// Sends the telemetry due at simulated time `t_us`.
    fn telemetry<S: MavSink>(&mut self, t_us: u64, out: &mut S) -> Result<(), S::Error> {
        if t_us >= self.next_us[0] {
            self.next_us[0] = t_us + 1_000_000 / HEARTBEAT_HZ;
            let hb = MavMessage::HEARTBEAT(hil::heartbeat(self.armed));
            out.send(Peer::Simulator, &hb)?;
            out.send(Peer::GroundStation, &hb)?;
        }
        if t_us >= self.next_us[1] {
            self.next_us[1] = t_us + 1_000_000 / SYS_STATUS_HZ;
            out.send(Peer::GroundStation, &MavMessage::SYS_STATUS(self.sys_status()))?;
        }
        if t_us >= self.next_us[2] {
            self.next_us[2] = t_us + 1_000_000 / ATTITUDE_HZ;
            if let Some(e) = self.core.navigator().estimate() {
                let rpy = fc_core::quat_to_euler(&e.att);
                out.send(
                    Peer::GroundStation,
                    &MavMessage::ATTITUDE(ATTITUDE_DATA {
                        time_boot_ms: boot_ms(t_us),
                        roll: rpy[0],
                        pitch: rpy[1],
                        yaw: rpy[2],
                        rollspeed: e.rates_frd_radps[0],
                        pitchspeed: e.rates_frd_radps[1],
                        yawspeed: e.rates_frd_radps[2],
                    }),
                )?;
                out.send(
                    Peer::GroundStation,
                    &MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
                        time_boot_ms: boot_ms(t_us),
                        x: e.pos_ned_m[0],
                        y: e.pos_ned_m[1],
                        z: e.pos_ned_m[2],
                        vx: e.vel_ned_mps[0],
                        vy: e.vel_ned_mps[1],
                        vz: e.vel_ned_mps[2],
                    }),
                )?;
            }
        }
        Ok(())
    }

    fn sys_status(&self) -> SYS_STATUS_DATA {
        use MavSysStatusSensor as S;
        let present = S::MAV_SYS_STATUS_SENSOR_3D_GYRO
            | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
            | S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS;
        let mut healthy = present;
        if self.core.navigator().mode() != NavMode::Navigating || self.core.failsafe() {
            healthy.remove(S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL);
        }
        // Load: the last step's time against a 1 kHz step, per mille.
        let per_step = u64::from(self.cycles.1) / 1000;
        let load = (u64::from(self.cycles.0) * 1000).checked_div(per_step).unwrap_or(0);
        SYS_STATUS_DATA {
            onboard_control_sensors_present: present,
            onboard_control_sensors_enabled: present,
            onboard_control_sensors_health: healthy,
            load: load.min(1000) as u16,
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
    let acc_masked = mask.intersects(
        T::POSITION_TARGET_TYPEMASK_AX_IGNORE
            | T::POSITION_TARGET_TYPEMASK_AY_IGNORE
            | T::POSITION_TARGET_TYPEMASK_AZ_IGNORE,
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
    if !acc_masked {
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
