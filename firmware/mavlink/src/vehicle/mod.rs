//! The flight controller as a MAVLink vehicle: [`MavVehicle`] takes the
//! messages of a simulator (PX4's HIL interface) and of a ground station,
//! runs the flight loop ([`fc_loop::Loop`] and its controller) on them,
//! and answers. It is two parts, as the CRTP vehicle is: [`MavShared`]
//! (everything but the controller) and the controller. In one process
//! they step together; an image that runs the estimator, the controller
//! and the link as tasks of their own splits them ([`MavVehicle::split`]):
//! [`MavShared::sensor_begin`], [`fly_sensor_step`],
//! [`MavShared::sensor_end`], and [`MavShared::handle`] for the rest.
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
use crate::mission::Mission;
use crate::modes::{FlightMode, NavSettings, Px4Mode};
use crate::params::{self, Refusal, Settings, PARAMS};
use crate::MavMessage;
use fc_core::control::AnyController;
use fc_core::control::Setpoint;
use fc_core::estimate::Fix;
#[cfg(test)]
use fc_core::model::airframe::MixerError;
use fc_loop::modes::{ModeCommander, ModeEvent};
use fc_loop::nav::NavMode;
use fc_loop::schedule::Schedule;
use fc_loop::{Exclusive, FcConfig, Loop};
use hal_shim::CycleClock;
use mavlink::dialects::common::*;
use nalgebra::Vector3;

mod commands;
mod faults;
mod flight;
mod missions;
mod parameters;
mod sensors;
mod streams;

pub use commands::autopilot_version;
#[cfg(test)]
use commands::FORCE;
pub use flight::{setpoint_from_target, streamed_jerk, JERK_GAP_MAX_MS, JERK_MAX_MPS3};
#[cfg(test)]
use parameters::param_id;
pub use parameters::{param_index_of, PARAM_COUNT};
pub use sensors::{fly_sensor_step, SensorStep, MAG_IMPLAUSIBLE_RAD, POSITION_IMPLAUSIBLE_M};
pub use streams::{Stream, MIN_INTERVAL_US, STREAMS};

pub use crate::{MavSink, Peer};

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
    /// Mode events not told: more in one step than
    /// [`MODE_EVENTS_PER_STEP`] (never, as the modes are written).
    pub events_dropped: u32,
}

/// The most mode events one step keeps for the ground station: the
/// ground-station failsafe's and the mode's
/// ([`fc_loop::modes::ModeCommander::fly`] says at most one).
pub const MODE_EVENTS_PER_STEP: usize = 2;

/// Height above the arming point from which the vehicle is in the air, m.
pub use fc_loop::modes::IN_AIR_M;

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

/// The flight controller behind MAVLink (see the module's documentation):
/// its state ([`MavShared`]) and its controller, stepped together. An
/// image that runs the estimator and the controller in tasks of their own
/// splits it ([`MavVehicle::split`]).
pub struct MavVehicle {
    shared: MavShared,
    /// The running controller.
    ctrl: AnyController<f32>,
}

impl core::ops::Deref for MavVehicle {
    type Target = MavShared;
    fn deref(&self) -> &MavShared {
        &self.shared
    }
}

impl core::ops::DerefMut for MavVehicle {
    fn deref_mut(&mut self) -> &mut MavShared {
        &mut self.shared
    }
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
            ctrl: fc_loop::fallback_controller(settings.vehicle),
            shared: MavShared::unstarted(settings, system_id),
        }
    }

    /// Checks the settings and designs the controller in place; the
    /// session is open from then on (set-points may come before samples).
    pub fn start(&mut self) -> Result<(), Refusal> {
        fc_loop::start_front_end(&mut self.shared.lp, &mut self.ctrl)
    }

    /// The vehicle's state and its controller apart, for an image that
    /// steps them in tasks of their own ([`MavShared::sensor_begin`],
    /// [`fly_sensor_step`], [`MavShared::sensor_end`]).
    pub fn split(&mut self) -> (&mut MavShared, &mut AnyController<f32>) {
        (&mut self.shared, &mut self.ctrl)
    }

    /// Handles one message ([`MavShared::handle`] with this vehicle's
    /// controller); answers go to `out`. `now_us` is the caller's clock
    /// (only a free-running loop uses it).
    pub fn handle<S: MavSink, C: CycleClock>(
        &mut self,
        msg: &MavMessage,
        out: &mut S,
        clock: &C,
        now_us: u64,
    ) -> Result<(), S::Error> {
        self.shared.handle(&mut self.ctrl, msg, out, clock, now_us)
    }

    /// Sets parameter `index` to `value`: checked, and applied to the
    /// controller (re-designed while disarmed), the mixer and the failsafe.
    pub fn apply(&mut self, index: usize, value: f32) -> Result<(), Refusal> {
        self.shared.apply(&mut self.ctrl, index, value)
    }
}

/// The MAVLink vehicle without its controller: the modes, the mission, the
/// streams and the flight loop ([`Loop`]). An image's tasks share it: the
/// estimator's half of a sample ([`MavShared::sensor_begin`]), the
/// controller's ([`fly_sensor_step`]) and the step's end
/// ([`MavShared::sensor_end`]) lock it in turn, and the link's task
/// handles a ground station's messages on it ([`MavShared::handle`]).
pub struct MavShared {
    lp: Loop,
    /// The flight mode, arming, home and what each mode flies
    /// ([`fc_loop::modes`]); its times are simulated µs.
    modes: ModeCommander,
    /// The mission store and its transfers.
    mission: Mission,
    /// What the commander's part of this step did, for its end to tell
    /// ([`MavShared::command`]).
    events: heapless::Vec<ModeEvent, MODE_EVENTS_PER_STEP>,
    /// The last streamed acceleration and its sender's time
    /// (`time_boot_ms`), for the jerk the message has no field for.
    offboard_acc: Option<(Vector3<f32>, u32)>,
    /// The simulator's first position: the origin of the local frame.
    home: Option<Home>,
    /// Time of the last fix taken, µs.
    last_fix_us: Option<u64>,
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
    /// The controller previews what the commander will fly (off: it
    /// extrapolates each step's set-point; [`MavShared::set_exact_preview`]).
    exact_preview: bool,
    /// The faults injected into the simulator's data, and each source's
    /// health (`faults`; with `sensor-faults`, as the SIL and
    /// `firmware-mavlink` build it: without, a stand-in that does nothing).
    faults: faults::Faults,
}

/// Milliseconds since boot of simulated time `t_us` (MAVLink's `time_boot_ms`).
fn boot_ms(t_us: u64) -> u32 {
    (t_us / 1000) as u32
}

/// A command, from `COMMAND_LONG` or `COMMAND_INT` (its x and y as f32).
struct Command {
    command: MavCmd,
    params: [f32; 7],
}

impl fc_loop::HoldsLoop for MavShared {
    fn flight_loop_mut(&mut self) -> &mut Loop {
        &mut self.lp
    }
}

impl MavShared {
    /// The state with nothing designed yet ([`MavVehicle::unstarted`]).
    fn unstarted(settings: Settings, system_id: u8) -> Self {
        Self {
            lp: Loop::unstarted_with(FcConfig::default(), settings),
            modes: ModeCommander::new(),
            mission: Mission::new(),
            events: heapless::Vec::new(),
            offboard_acc: None,
            home: None,
            last_fix_us: None,
            mag_ref_rad: None,
            mag_due: Schedule::new(),
            last_sensor_us: None,
            seq: 0,
            motors: [0.0; 4],
            cycles: (0, 1),
            streams: STREAMS.map(|s| (s.interval_us, 0)),
            link_errors: 0,
            reported_ned_m: None,
            counters: VehicleCounters::default(),
            system_id,
            exact_preview: true,
            faults: faults::Faults::new(),
        }
    }

    /// Armed (the motors turn).
    pub fn armed(&self) -> bool {
        self.modes.armed()
    }

    /// The supervisor's gate: the motors turn, as PX4's do from arming
    /// (every armed step flies: the modes' failsafes are set-points, Hold
    /// and Land). The power stage's `fly` and the parameters' write rule
    /// ([`fc_loop::Loop::write_param`]).
    pub fn motors_turn(&self) -> bool {
        self.modes.armed()
    }

    /// The settings in force (the parameters' values).
    pub fn settings(&self) -> &Settings {
        self.lp.settings()
    }

    /// The flight loop (its estimator, set-point, counters).
    pub fn flight_loop(&self) -> &Loop {
        &self.lp
    }

    /// The set-point the commander flies ([`fc_loop::commander`]): the
    /// flight loop's from the next step on (a command between two steps
    /// changes this one, the loop's at the next).
    pub fn setpoint(&self) -> Setpoint<f32> {
        self.modes.setpoint(self.last_sensor_us.unwrap_or(0), &self.lp)
    }

    /// Flies trajectory `id` of `memory` from `start_us` (the simulator's
    /// µs) as if a client had uploaded it, relative to the set-point flown
    /// when `options` say so (`ModeCommander::fly_trajectory`: Offboard
    /// and armed; nothing changes if refused). A host's way in
    /// (`sil-host px4-hil --trajectory`, feature `handover`): no MAVLink
    /// message uploads one.
    #[cfg(feature = "handover")]
    pub fn fly_trajectory(
        &mut self,
        memory: &'static fc_loop::trajectory::TrajectoryMemory,
        id: u8,
        options: fc_loop::trajectory::StartOptions,
        start_us: u64,
    ) -> Result<(), fc_loop::modes::ModeRefusal> {
        let t_us = self.last_sensor_us.unwrap_or(0);
        self.modes.fly_trajectory(memory, id, options, start_us, t_us, &self.lp)
    }

    /// Whether the controller previews what the commander will fly (on
    /// from boot), or extrapolates each step's set-point along its own
    /// derivatives as it does a stream's: a measurement's switch, what the
    /// preview is worth (`sil-host px4-hil --no-preview`), not a parameter.
    pub fn set_exact_preview(&mut self, on: bool) {
        self.exact_preview = on;
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

    /// Handles one message; answers go to `out`. `ctrl` is the vehicle's
    /// controller: a `HIL_SENSOR` steps it (the three halves of
    /// [`MavShared::sensor_begin`] in one call), arming and a parameter
    /// write design it. `now_us` is the caller's clock (only a
    /// free-running loop uses it).
    // MISSION_REQUEST and MISSION_SET_CURRENT are deprecated, and sent.
    #[allow(deprecated)]
    pub fn handle<S: MavSink, C: CycleClock>(
        &mut self,
        ctrl: &mut AnyController<f32>,
        msg: &MavMessage,
        out: &mut S,
        clock: &C,
        now_us: u64,
    ) -> Result<(), S::Error> {
        match msg {
            MavMessage::HIL_SENSOR(m) => {
                let Some(step) = self.sensor_begin(m, clock, now_us) else {
                    return Ok(());
                };
                let flown = fly_sensor_step(&mut Exclusive(&mut *self), ctrl, &step, clock);
                self.sensor_end(&step, flown, clock, out)
            }
            MavMessage::HIL_STATE_QUATERNION(m) => {
                self.on_state(m);
                Ok(())
            }
            MavMessage::COMMAND_LONG(m) if self.for_me(m.target_system) => {
                let c = Command {
                    command: m.command,
                    params: [m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7],
                };
                self.on_command(ctrl, &c, out)
            }
            MavMessage::COMMAND_INT(m) if self.for_me(m.target_system) => {
                // x and y are integers (degrees × 1e7 in global frames);
                // none of the commands answered here reads them.
                let c = Command {
                    command: m.command,
                    params: [m.param1, m.param2, m.param3, m.param4, m.x as f32, m.y as f32, m.z],
                };
                self.on_command(ctrl, &c, out)
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
                self.on_command(ctrl, &c, out)
            }
            MavMessage::SETUP_SIGNING(m) if self.for_me(m.target_system) => {
                let armed = self.modes.armed();
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
                self.modes
                    .manual([m.x, m.y, m.z, m.r], self.last_sensor_us.unwrap_or(0));
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
                let reads = matches!(
                    msg,
                    MavMessage::MISSION_REQUEST_LIST(_)
                        | MavMessage::MISSION_REQUEST_INT(_)
                        | MavMessage::MISSION_REQUEST(_)
                        | MavMessage::MISSION_ACK(_)
                );
                if !reads {
                    let mut flown = missions::flown(&mut self.mission, self.home);
                    self.modes.mission_changing(t_us, &mut self.lp, &mut flown);
                }
                let home_down_m = self.modes.home_ned_m()[2];
                self.mission.handle(msg, t_us, self.home.as_ref(), home_down_m, out)?;
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
            MavMessage::PARAM_SET(m) if self.for_me(m.target_system) => self.on_param_set(ctrl, m, out),
            MavMessage::HEARTBEAT(h) => {
                if h.mavtype == MavType::MAV_TYPE_GCS {
                    self.modes.ground_station_heard(self.last_sensor_us.unwrap_or(0));
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

    /// The flight mode.
    pub fn mode(&self) -> FlightMode {
        self.modes.mode()
    }

    /// The automatic modes' settings (PX4's parameters).
    pub fn nav_settings(&self) -> &NavSettings {
        &self.lp.settings().nav
    }

    /// A `STATUSTEXT` naming parameter `id` and why it was refused.
    fn status<S: MavSink>(&self, out: &mut S, sev: MavSeverity, id: &[u8], why: Refusal) -> Result<(), S::Error> {
        let len = id.iter().position(|&b| b == 0).unwrap_or(id.len());
        let name = core::str::from_utf8(&id[..len]).unwrap_or("?");
        self.say(out, sev, format_args!("{name}: {why}"))
    }

    /// Sends a `STATUSTEXT` (cut at 50 characters).
    fn say<S: MavSink>(&self, out: &mut S, severity: MavSeverity, text: core::fmt::Arguments) -> Result<(), S::Error> {
        say(out, severity, text)
    }
}

/// Sends a `STATUSTEXT` (cut at 50 characters) to the ground station.
fn say<S: MavSink>(out: &mut S, severity: MavSeverity, text: core::fmt::Arguments) -> Result<(), S::Error> {
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

#[cfg(test)]
mod tests;
#[cfg(all(test, feature = "sensor-faults"))]
mod tests_faults;
