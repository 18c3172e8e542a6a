//! The flight modes a ground station commands, as PX4's commander and
//! navigator fly them, for any protocol that commands by mode:
//! [`ModeCommander`] holds the mode, arming and home, decides whether a mode
//! may be entered ([`ModeRefusal`]), and each step sets the flight loop's
//! set-point from what the mode flies and its failsafes, saying what
//! happened as a [`ModeEvent`]. The protocol's adapter (fc-mavlink) only
//! decodes into its calls and encodes its events; PX4's numbers for the
//! modes are the adapter's.
//!
//! | mode | what it flies |
//! |---|---|
//! | Position | holds where it was when entered; a joystick ([`ModeCommander::manual`]) moves it ([`joystick_velocity`]); a joystick heard and then silent for `manual_loss_s` → Land |
//! | Hold | the same, without a joystick (PX4's loiter) |
//! | Takeoff | straight up to [`NavSettings::takeoff_alt_m`] above home, then Hold |
//! | Land | straight down to the ground it armed on at [`NavSettings::land_mps`], then disarms |
//! | Return | up to [`NavSettings::rtl_alt_m`] above home (if lower), over home at [`NavSettings::cruise_mps`], then down and disarmed |
//! | Offboard | a client's streamed set-points ([`ModeCommander::offboard`]); entered only while they stream, Hold when they stop for [`NavSettings::offboard_loss_s`]; or a trajectory its host handed the vehicle (`ModeCommander::fly_trajectory`, feature `handover`), not watched for a stream while it flies |
//! | Mission | the uploaded mission ([`MissionItems`]), item by item; then Hold |
//!
//! The modes are a source of set-points on the [`Commander`], as CRTP's
//! set-points and high-level commander are: a hold, the joystick's and
//! Offboard's set-points are held as given ([`Commander::hold`]); each leg
//! of an automatic mode is one planner segment
//! ([`crate::planner::Segment`], rest to rest, [`Route`],
//! [`Commander::follow`]), its duration chosen so that its peak speed is
//! the mode's speed. Each step ([`ModeCommander::fly`]) hands the
//! commander's set-point to the flight loop. A ground station
//! heard and then silent for `gcs_loss_ms` (the settings' `FS_GCS_MS`)
//! while armed → Land ([`ModeCommander::watch_ground_station`]).
//!
//! The supervisor's tumble check ([`crate::supervisor::tumbled`], the one
//! the CRTP vehicle stops its motors on) runs as PX4's failure detector
//! does with its defaults: tilted beyond 60° from arming until
//! [`LOCKDOWN_AFTER_TAKEOFF_US`] after the take-off, the motors stop
//! (PX4's lockdown, [`ModeEvent::Lockdown`]: a vehicle that flips as it
//! lifts off, a motor wired in the wrong place); later in the flight
//! nothing is cut (PX4's flight termination is off by default,
//! `CBRK_FLIGHTTERM`).

use crate::arming::{ArmRefusal, Arming, ArmingState};
use crate::commander::{Commander, Legs, Route};
use crate::nav::NavMode;
use crate::planner::Reference;
use crate::trajectory::TrajectoryError;
#[cfg(feature = "handover")]
use crate::trajectory::{Flight, StartOptions, TrajectoryMemory};
use crate::{AnyController, Exclusive, Loop};
use fc_core::control::Setpoint;
use nalgebra::Vector3;

mod mission;
mod settings;
#[cfg(test)]
mod tests;

use mission::MissionPhase;
pub use mission::{MissionAction, MissionItems};
pub use settings::{joystick_velocity, NavSettings};

/// Height above the arming point from which the vehicle is in the air, m.
pub const IN_AIR_M: f32 = 0.15;

/// How long after the take-off (the first step in the air, [`IN_AIR_M`])
/// a tumble still locks the motors down, µs (PX4's `COM_LKDOWN_TKO`, 3 s).
pub const LOCKDOWN_AFTER_TAKEOFF_US: u64 = 3_000_000;

/// A flight mode (see the module's table).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FlightMode {
    /// Position control: hold where it is, moved by a joystick.
    Position,
    /// Hold (PX4's AUTO LOITER).
    Hold,
    /// Climb to the takeoff height, then Hold.
    Takeoff,
    /// Descend to the ground, then disarm.
    Land,
    /// Return to home and land.
    Return,
    /// Fly the ground station's set-points.
    Offboard,
    /// Fly the uploaded mission.
    Mission,
}

impl FlightMode {
    /// Every mode.
    pub const ALL: [FlightMode; 7] = [
        FlightMode::Position,
        FlightMode::Hold,
        FlightMode::Takeoff,
        FlightMode::Land,
        FlightMode::Return,
        FlightMode::Offboard,
        FlightMode::Mission,
    ];

    /// The name QGroundControl shows for it.
    pub const fn name(self) -> &'static str {
        match self {
            FlightMode::Position => "Position",
            FlightMode::Hold => "Hold",
            FlightMode::Takeoff => "Takeoff",
            FlightMode::Land => "Land",
            FlightMode::Return => "Return",
            FlightMode::Offboard => "Offboard",
            FlightMode::Mission => "Mission",
        }
    }
}

impl core::fmt::Display for FlightMode {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// Why a mode was not entered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModeRefusal {
    /// Offboard without a fresh streamed set-point.
    NotStreaming,
    /// Mission with no mission uploaded.
    NoMission,
    /// An automatic mode that needs the motors turning.
    Disarmed,
    /// An automatic mode without an estimated position.
    NoPosition,
    /// A leg's goal is not finite or out of the planner's reach.
    OutOfRange,
    /// A trajectory outside Offboard, or one that cannot start (see the error).
    Trajectory(Option<TrajectoryError>),
}

impl core::fmt::Display for ModeRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            ModeRefusal::NotStreaming => "no set-points streaming",
            ModeRefusal::NoMission => "no mission",
            ModeRefusal::Disarmed => "disarmed",
            ModeRefusal::NoPosition => "no position",
            ModeRefusal::OutOfRange => "goal out of range",
            ModeRefusal::Trajectory(None) => "a trajectory flies in Offboard only",
            ModeRefusal::Trajectory(Some(e)) => return write!(f, "trajectory: {e}"),
        })
    }
}

/// Why a disarm was refused ([`ModeCommander::request_disarm`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DisarmRefusal {
    /// More than [`IN_AIR_M`] above where it armed: disarming would drop it.
    InAir,
}

impl core::fmt::Display for DisarmRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            DisarmRefusal::InAir => "in the air",
        })
    }
}

/// A landing without a position ends this long after the descent its
/// height needed ([`ModeCommander::watch_position`]), µs.
pub const BLIND_LANDING_MARGIN_US: u64 = 3_000_000;

/// Something a step did that the ground station should hear of.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModeEvent {
    /// The takeoff height is reached: Hold.
    TakeoffDone,
    /// A landing (Land, a return's last leg) ended on the ground: disarmed.
    Landed,
    /// Offboard's set-points stopped: Hold.
    OffboardLost,
    /// The joystick went silent in Position mode: Land.
    JoystickLost,
    /// The ground station went silent while armed: Land.
    GroundStationLost,
    /// The position is not known (its fix lost or refused, the
    /// estimator's failsafe) while armed: Land (PX4's failsafe without a
    /// position: descend).
    PositionLost,
    /// A part of the IMU stopped answering, or answered the same, while
    /// armed in the air: Land on what stands in for it (the gyro's recent
    /// mean, the commanded thrust's specific force; with
    /// `sensor-faults`).
    ImuLost,
    /// The gyro stayed silent in the air: the motors stopped (PX4's flight
    /// termination; with `sensor-faults`).
    GyroDead,
    /// Mission item `seq` is done; item `next` is current now (as the
    /// mission store has it: never past its end).
    ItemReached {
        /// The item done.
        seq: u16,
        /// The item current now.
        next: u16,
    },
    /// The mission's last item is done: Hold.
    MissionDone,
    /// Mission item `seq` cannot be flown by this vehicle: Hold.
    ItemNotFlyable(u16),
    /// Mission item `seq` is out of the planner's reach: Hold.
    ItemOutOfRange(u16),
    /// Tilted beyond [`crate::supervisor::TUMBLE_TILT_RAD`] on the ground
    /// or right after the take-off: disarmed (PX4's lockdown).
    Lockdown,
}

impl ModeEvent {
    /// A failsafe (rather than news of a plan going as planned).
    pub fn is_failsafe(self) -> bool {
        matches!(
            self,
            ModeEvent::JoystickLost
                | ModeEvent::GroundStationLost
                | ModeEvent::PositionLost
                | ModeEvent::ImuLost
                | ModeEvent::GyroDead
                | ModeEvent::Lockdown
        )
    }
}

impl core::fmt::Display for ModeEvent {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            ModeEvent::TakeoffDone => f.write_str("takeoff done: hold"),
            ModeEvent::Landed => f.write_str("landed: disarmed"),
            ModeEvent::OffboardLost => f.write_str("offboard set-points lost: hold"),
            ModeEvent::JoystickLost => f.write_str("joystick lost: landing"),
            ModeEvent::GroundStationLost => f.write_str("ground station lost: landing"),
            ModeEvent::PositionLost => f.write_str("no position: landing"),
            ModeEvent::ImuLost => f.write_str("IMU lost: landing"),
            ModeEvent::GyroDead => f.write_str("no gyro: motors off"),
            ModeEvent::ItemReached { seq, .. } => write!(f, "mission item {seq} reached"),
            ModeEvent::MissionDone => f.write_str("mission done: hold"),
            ModeEvent::ItemNotFlyable(seq) => write!(f, "mission item {seq} cannot be flown: hold"),
            ModeEvent::ItemOutOfRange(seq) => write!(f, "mission item {seq} out of range: hold"),
            ModeEvent::Lockdown => f.write_str("critical failure: tilt beyond 60°, lockdown"),
        }
    }
}

/// PX4's landed state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LandedState {
    /// Disarmed, or armed on the ground.
    OnGround,
    /// Climbing in Takeoff.
    Takeoff,
    /// Armed and in the air.
    InAir,
    /// Coming down to land, in the air.
    Landing,
}

/// A vehicle commanded by mode (see the module's documentation). Times are
/// the flight loop's (simulated or board) µs.
#[derive(Debug, Clone)]
pub struct ModeCommander {
    mode: FlightMode,
    /// Armed (PX4's lockdown disarms; nothing here locks or latches a
    /// tumble).
    arming: Arming,
    /// The set-point flown: the modes' source on it.
    commander: Commander,
    /// The automatic mode's legs after the one flown.
    route: Route,
    /// The mission item flown (Mission mode).
    phase: Option<MissionPhase>,
    /// A mission's speed change, for the rest of it, m/s.
    mission_cruise_mps: Option<f32>,
    /// The last streamed set-point, and when it came.
    offboard: Option<(Setpoint<f32>, u64)>,
    /// The joystick's last deflection (x, y, z, r), and when it came.
    manual: Option<([i16; 4], u64)>,
    /// When a ground station was last heard.
    gcs_seen_us: Option<u64>,
    /// Where it armed (estimated), NED about the origin, m: the home a
    /// return flies to (the origin until it arms).
    home_ned_m: Vector3<f32>,
    /// When it was first in the air since it armed (the take-off), µs.
    takeoff_us: Option<u64>,
    /// A landing's ground contact by thrust ([`crate::land::GroundContact`]).
    #[cfg(feature = "sensor-faults")]
    contact: crate::land::GroundContact,
    /// A landing without a position ends by this time, µs
    /// ([`ModeCommander::watch_position`]).
    #[cfg(feature = "sensor-faults")]
    blind_until_us: Option<u64>,
    /// The trajectory memory a host handed over with a trajectory to fly
    /// (`ModeCommander::fly_trajectory`, feature `handover`); the images
    /// speak no trajectory upload over MAVLink and have none.
    #[cfg(feature = "handover")]
    trajectories: Option<&'static TrajectoryMemory>,
}

impl Default for ModeCommander {
    fn default() -> Self {
        Self::new()
    }
}

impl ModeCommander {
    /// Disarmed in Position mode, home at the origin, default settings.
    pub const fn new() -> Self {
        Self {
            mode: FlightMode::Position,
            arming: Arming::new(),
            commander: Commander::new(),
            route: Route::new(),
            phase: None,
            mission_cruise_mps: None,
            offboard: None,
            manual: None,
            gcs_seen_us: None,
            home_ned_m: Vector3::new(0.0, 0.0, 0.0),
            takeoff_us: None,
            #[cfg(feature = "sensor-faults")]
            contact: crate::land::GroundContact::new(),
            #[cfg(feature = "sensor-faults")]
            blind_until_us: None,
            #[cfg(feature = "handover")]
            trajectories: None,
        }
    }

    /// The mode.
    pub fn mode(&self) -> FlightMode {
        self.mode
    }

    /// The commander the modes fly their set-points on (its source, and
    /// the preview of what it will fly: [`Commander::preview_at`]).
    pub fn commander(&self) -> &Commander {
        &self.commander
    }

    /// Armed (the motors turn).
    pub fn armed(&self) -> bool {
        self.arming.armed()
    }

    /// Where it armed, NED about the origin, m.
    pub fn home_ned_m(&self) -> Vector3<f32> {
        self.home_ned_m
    }

    /// The set-point flown at `t_us` (the last step's time: the one the
    /// flight loop flies from the next step), or the loop's `lp` if the
    /// commander has none yet (before the first arming): where a new leg
    /// starts, the heading a set-point that masks its own keeps.
    pub fn setpoint(&self, t_us: u64, lp: &Loop) -> Setpoint<f32> {
        self.commander
            .setpoint_at(t_us, &self.trajectories())
            .unwrap_or(*lp.setpoint())
    }

    /// Flies `legs` from the set-point `from` at `t_us`, at its heading
    /// (`lands`: the last leg is a landing): the route's first segment on
    /// the commander; `false` if no leg could be planned.
    fn start_route(&mut self, t_us: u64, from: &Setpoint<f32>, legs: Legs, lands: bool) -> bool {
        let Some((seg, landing)) = self
            .route
            .start(t_us, &Reference::from(from), legs, from.yaw_rad, lands)
        else {
            return false;
        };
        self.commander.plan(seg, landing);
        true
    }

    /// The trajectory memory the commander's trajectory is evaluated from
    /// (none unless a host handed one over).
    #[cfg(feature = "handover")]
    pub fn trajectories(&self) -> Option<&'static TrajectoryMemory> {
        self.trajectories
    }

    /// No trajectory memory: no trajectory is handed over without the
    /// feature `handover`, and none is evaluated.
    #[cfg(not(feature = "handover"))]
    pub fn trajectories(&self) -> crate::trajectory::NoTrajectories {
        crate::trajectory::NoTrajectories
    }

    /// Flies trajectory `id` of `memory` from `start_us` with `options` (a
    /// relative start from the set-point flown at `t_us`): a trajectory a
    /// host hands the vehicle as if uploaded, as a Crazyflie's
    /// high-level commander flies one. Offboard and armed only; while it
    /// flies (and rests at its end) Offboard's stream is not watched, and a
    /// streamed set-point takes over. Nothing changes if it is refused.
    #[cfg(feature = "handover")]
    pub fn fly_trajectory(
        &mut self,
        memory: &'static TrajectoryMemory,
        id: u8,
        options: StartOptions,
        start_us: u64,
        t_us: u64,
        lp: &Loop,
    ) -> Result<(), ModeRefusal> {
        if !self.armed() {
            return Err(ModeRefusal::Disarmed);
        }
        if self.mode != FlightMode::Offboard {
            return Err(ModeRefusal::Trajectory(None));
        }
        let from = Reference::from(&self.setpoint(t_us, lp));
        let flight =
            Flight::start(memory, id, start_us, options, &from).map_err(|e| ModeRefusal::Trajectory(Some(e)))?;
        self.trajectories = Some(memory);
        self.commander.fly_trajectory(flight);
        Ok(())
    }

    /// The last streamed set-point and when it came, if any.
    pub fn streamed(&self) -> Option<(Setpoint<f32>, u64)> {
        self.offboard
    }

    /// How long Offboard's set-points may be silent, µs (`COM_OF_LOSS_T`).
    fn offboard_loss_us(nav: &NavSettings) -> u64 {
        (nav.offboard_loss_s * 1e6) as u64
    }

    /// A client's set-point at `t_us`: kept for Offboard, and flown from
    /// the next step in Offboard while armed (as PX4 does, a stream outside
    /// Offboard only makes Offboard possible).
    pub fn offboard(&mut self, sp: Setpoint<f32>, t_us: u64) {
        self.offboard = Some((sp, t_us));
        if self.mode == FlightMode::Offboard && self.armed() {
            self.commander.hold(sp);
        }
    }

    /// A joystick's deflection (see [`joystick_velocity`]) at `t_us`.
    pub fn manual(&mut self, sticks: [i16; 4], t_us: u64) {
        self.manual = Some((sticks, t_us));
    }

    /// A ground station was heard at `t_us`.
    pub fn ground_station_heard(&mut self, t_us: u64) {
        self.gcs_seen_us = Some(t_us);
    }

    /// Armed and more than [`IN_AIR_M`] above where it armed (estimated):
    /// disarming would drop it.
    pub fn in_air(&self, lp: &Loop) -> bool {
        let down = lp.navigator().estimate().map(|e| e.pos_ned_m[2]);
        self.armed() && down.is_some_and(|d| d < self.home_ned_m[2] - IN_AIR_M)
    }

    /// A landing is flown: Land, or a return's last leg (straight down over
    /// home).
    fn landing(&self) -> bool {
        self.mode == FlightMode::Land || (self.mode == FlightMode::Return && self.commander.is_landing())
    }

    /// PX4's landed state: on the ground, taking off, in the air, landing.
    pub fn landed_state(&self, lp: &Loop) -> LandedState {
        match (self.armed(), self.in_air(lp)) {
            (false, _) => LandedState::OnGround,
            (true, _) if self.mode == FlightMode::Takeoff => LandedState::Takeoff,
            (true, true) if self.landing() => LandedState::Landing,
            (true, true) => LandedState::InAir,
            (true, false) => LandedState::OnGround,
        }
    }

    /// Arms if the estimator navigates and the vehicle is `started`; the
    /// controller `ctrl` of the loop `lp` is designed afresh (no state wound up on the ground).
    /// Where it arms is home; it holds there (or, in Offboard, flies the
    /// streamed set-point; an automatic mode becomes Hold). Nothing else is
    /// checked here: PX4's HIL gives no battery reading, and nothing locks
    /// (a tumble is the lockdown's, [`ModeCommander::fly`]).
    pub fn arm(&mut self, lp: &mut Loop, ctrl: &mut AnyController<f32>, started: bool) -> Result<(), ArmRefusal> {
        let estimate = lp.navigator().estimate();
        let nav = match (lp.navigator().mode(), estimate) {
            (NavMode::Navigating, None) => NavMode::Failsafe,
            (mode, _) => mode,
        };
        let state = ArmingState {
            sensor_down: None,
            battery_v: None,
            battery_floor_v: 0.0,
            nav,
            started,
        };
        let spec = lp.settings().controller;
        let prepared = self.arming.arm(&state, || {
            let est = estimate.ok_or(ArmRefusal::EstimatorFailsafe)?;
            crate::select(&mut Exclusive(&mut *lp), ctrl, spec).map_err(|_| ArmRefusal::DesignFailed)?;
            Ok(est)
        })?;
        // Armed already: nothing changes.
        let Some(est) = prepared else {
            return Ok(());
        };
        let yaw = fc_core::quat_to_euler(&est.att)[2];
        match (self.mode, self.offboard) {
            (FlightMode::Offboard, Some((sp, _))) => {
                self.commander.hold(sp);
            }
            (mode, _) => {
                self.commander.hold(Setpoint::hold(est.pos_ned_m, yaw));
                if mode != FlightMode::Position {
                    self.mode = FlightMode::Hold;
                }
            }
        }
        self.home_ned_m = est.pos_ned_m;
        self.takeoff_us = None;
        Ok(())
    }

    /// A client's disarm: refused in the air ([`ModeCommander::in_air`]
    /// over the loop `lp`) unless `forced` (PX4's forced disarm), else
    /// disarmed ([`ModeCommander::disarm`]); `Ok(true)` if it was armed.
    pub fn request_disarm(&mut self, lp: &Loop, forced: bool) -> Result<bool, DisarmRefusal> {
        if self.in_air(lp) && !forced {
            return Err(DisarmRefusal::InAir);
        }
        let was_armed = self.armed();
        self.disarm();
        Ok(was_armed)
    }

    /// Disarms (an automatic mode becomes Hold).
    pub fn disarm(&mut self) {
        self.arming.disarm();
        #[cfg(feature = "sensor-faults")]
        {
            self.blind_until_us = None;
        }
        if !matches!(self.mode, FlightMode::Position | FlightMode::Offboard) {
            self.mode = FlightMode::Hold;
        }
    }

    /// Enters `mode` at `t_us`, or says why not. `takeoff_up_m` is a
    /// takeoff's height above the origin (NaN: [`NavSettings::takeoff_alt_m`]
    /// above home).
    pub fn set_mode<M: MissionItems + ?Sized>(
        &mut self,
        mode: FlightMode,
        t_us: u64,
        takeoff_up_m: f32,
        lp: &mut Loop,
        mission: &mut M,
    ) -> Result<(), ModeRefusal> {
        let nav = lp.settings().nav;
        let est = lp.navigator().estimate();
        let here = est.map(|e| e.pos_ned_m);
        let yaw = est.map_or(0.0, |e| fc_core::quat_to_euler(&e.att)[2]);
        match mode {
            FlightMode::Position | FlightMode::Hold => {
                if let (true, Some(p)) = (self.armed(), here) {
                    self.commander.hold(Setpoint::hold(p, yaw));
                }
            }
            FlightMode::Offboard => {
                let fresh = self
                    .offboard
                    .filter(|&(_, at)| t_us.saturating_sub(at) <= Self::offboard_loss_us(&nav));
                let Some((sp, _)) = fresh else {
                    return Err(ModeRefusal::NotStreaming);
                };
                if self.armed() {
                    self.commander.hold(sp);
                }
            }
            FlightMode::Mission => {
                if mission.is_empty() {
                    return Err(ModeRefusal::NoMission);
                }
                if !self.armed() {
                    return Err(ModeRefusal::Disarmed);
                }
                if usize::from(mission.current()) >= mission.len() {
                    mission.set_current(0);
                }
                self.phase = None;
                self.mission_cruise_mps = None;
            }
            FlightMode::Takeoff | FlightMode::Land | FlightMode::Return => {
                if !self.armed() {
                    return Err(ModeRefusal::Disarmed);
                }
                let Some(p) = here else {
                    return Err(ModeRefusal::NoPosition);
                };
                let ground = self.home_ned_m[2];
                let mut legs = Legs::new();
                let _ = match mode {
                    FlightMode::Takeoff => {
                        let up = if takeoff_up_m.is_finite() {
                            takeoff_up_m
                        } else {
                            nav.takeoff_alt_m - ground
                        };
                        legs.push_back((Vector3::new(p[0], p[1], -up), nav.climb_mps))
                    }
                    FlightMode::Land => legs.push_back((Vector3::new(p[0], p[1], ground), nav.land_mps)),
                    _ => {
                        // Return: up to RTL_RETURN_ALT (if lower), over home, down.
                        let cruise = p[2].min(ground - nav.rtl_alt_m);
                        let h = self.home_ned_m;
                        let _ = legs.push_back((Vector3::new(p[0], p[1], cruise), nav.climb_mps));
                        let _ = legs.push_back((Vector3::new(h[0], h[1], cruise), nav.cruise_mps));
                        legs.push_back((Vector3::new(h[0], h[1], ground), nav.land_mps))
                    }
                };
                let sp = self.setpoint(t_us, lp);
                let lands = mode != FlightMode::Takeoff;
                if !self.start_route(t_us, &sp, legs, lands) {
                    return Err(ModeRefusal::OutOfRange);
                }
            }
        }
        if mode != FlightMode::Mission {
            self.phase = None;
        }
        self.mode = mode;
        Ok(())
    }

    /// The mission is about to change (an upload, a clear, a new current
    /// item): the mission flown is not changed under it, Hold first.
    pub fn mission_changing<M: MissionItems + ?Sized>(&mut self, t_us: u64, lp: &mut Loop, mission: &mut M) {
        if self.mode == FlightMode::Mission {
            let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN, lp, mission);
        }
    }

    /// The ground-station failsafe (`gcs_loss_ms`, 0: off): armed, a ground
    /// station was heard, and it has been silent that long → Land (where it
    /// is, then disarmed on the ground). Set-points do not count; a
    /// heartbeat again does not cancel it (as PX4's data-link loss).
    pub fn watch_ground_station<M: MissionItems + ?Sized>(
        &mut self,
        t_us: u64,
        gcs_loss_ms: u32,
        lp: &mut Loop,
        mission: &mut M,
    ) -> Option<ModeEvent> {
        let limit_us = u64::from(gcs_loss_ms) * 1000;
        let lost = self.gcs_seen_us.is_some_and(|t| t_us.saturating_sub(t) > limit_us);
        if self.armed()
            && self.mode != FlightMode::Land
            && limit_us > 0
            && lost
            && self.set_mode(FlightMode::Land, t_us, f32::NAN, lp, mission).is_ok()
        {
            self.gcs_seen_us = None;
            return Some(ModeEvent::GroundStationLost);
        }
        None
    }

    /// The failsafe without a position: armed, in the air, and `known`
    /// false (the vehicle's position fix lost or refused, or the
    /// estimator's own failsafe) → Land, where the estimate says it is, as
    /// PX4 descends without a position. Once; a position again does not
    /// cancel it. A dead-reckoned height drifts, and a simulator's ground
    /// may stop the vehicle without the jolt an accelerometer would feel
    /// (rotorpy's does): so this landing also ends by time, as the
    /// Crazyflie's failsafe descent does, once the height the estimate had
    /// above home when the position was lost has been descended at the
    /// slower of the two descents (Land's, the estimator's failsafe's) and
    /// [`BLIND_LANDING_MARGIN_US`] more. With `sensor-faults` only.
    #[cfg(feature = "sensor-faults")]
    pub fn watch_position<M: MissionItems + ?Sized>(
        &mut self,
        t_us: u64,
        known: bool,
        lp: &mut Loop,
        mission: &mut M,
    ) -> Option<ModeEvent> {
        if known {
            return None;
        }
        self.land_blind(t_us, lp, mission).then_some(ModeEvent::PositionLost)
    }

    /// The failsafe without the IMU: armed, in the air, and `silent` (a
    /// part without a good reading for [`crate::supervisor::IMU_TIMEOUT_US`]:
    /// the vehicle steps on what stands in for it) → Land, as [`Self::watch_position`]
    /// lands (ending by time too: a held sample dead-reckons the height).
    /// With `sensor-faults` only.
    #[cfg(feature = "sensor-faults")]
    pub fn watch_imu<M: MissionItems + ?Sized>(
        &mut self,
        t_us: u64,
        silent: bool,
        lp: &mut Loop,
        mission: &mut M,
    ) -> Option<ModeEvent> {
        if !silent {
            return None;
        }
        self.land_blind(t_us, lp, mission).then_some(ModeEvent::ImuLost)
    }

    /// Land from where the estimate says the vehicle is, ending by time
    /// too ([`Self::watch_position`]); `false` when not armed in the air,
    /// or landing already.
    #[cfg(feature = "sensor-faults")]
    fn land_blind<M: MissionItems + ?Sized>(&mut self, t_us: u64, lp: &mut Loop, mission: &mut M) -> bool {
        if !self.armed() || self.mode == FlightMode::Land || self.takeoff_us.is_none() {
            return false;
        }
        let up_m = lp
            .navigator()
            .estimate()
            .map_or(0.0, |e| (self.home_ned_m[2] - e.pos_ned_m[2]).max(0.0));
        let speed = lp.settings().nav.land_mps.min(lp.navigator().config().descent_mps);
        if self.set_mode(FlightMode::Land, t_us, f32::NAN, lp, mission).is_err() {
            return false;
        }
        // At most a minute: a height the estimate got wrong is not flown for ever.
        let descent_us = (up_m / speed * 1e6).min(60e6) as u64;
        self.blind_until_us = Some(t_us + descent_us + BLIND_LANDING_MARGIN_US);
        true
    }

    /// Each step (at `t_us`, `dt_s` after the last): what the mode flies
    /// (a takeoff then holds; a landing disarms on the ground), its
    /// failsafes (Offboard's loss of set-points, then Hold; Position's lost
    /// joystick, then Land) and the mission's items; then the commander's
    /// set-point of this step into the flight loop. Each event is handed to
    /// `say` as it happens; its error ends the step.
    pub fn fly<M: MissionItems + ?Sized, E>(
        &mut self,
        t_us: u64,
        dt_s: f32,
        lp: &mut Loop,
        mission: &mut M,
        say: &mut impl FnMut(ModeEvent) -> Result<(), E>,
    ) -> Result<(), E> {
        if !self.armed() {
            return Ok(());
        }
        if self.lockdown(t_us, lp) {
            return say(ModeEvent::Lockdown);
        }
        self.fly_mode(t_us, dt_s, lp, mission, say)?;
        if let Some(sp) = self.commander.setpoint_at(t_us, &self.trajectories()) {
            lp.set_setpoint(&sp);
        }
        Ok(())
    }

    /// What the mode flies this step, and its failsafes ([`Self::fly`]).
    fn fly_mode<M: MissionItems + ?Sized, E>(
        &mut self,
        t_us: u64,
        dt_s: f32,
        lp: &mut Loop,
        mission: &mut M,
        say: &mut impl FnMut(ModeEvent) -> Result<(), E>,
    ) -> Result<(), E> {
        let nav = lp.settings().nav;
        match self.mode {
            FlightMode::Position => self.fly_joystick(t_us, dt_s, lp, mission, say),
            FlightMode::Takeoff | FlightMode::Land | FlightMode::Return => {
                let Some(done) = self.commander.follow(&mut self.route, t_us) else {
                    return Ok(());
                };
                if self.mode == FlightMode::Takeoff && done {
                    self.mode = FlightMode::Hold;
                    return say(ModeEvent::TakeoffDone);
                }
                // Landed (crate::land): landing, on the ground it armed on
                // and not moving up or down.
                let on_ground = lp
                    .navigator()
                    .estimate()
                    .is_some_and(|e| crate::land::on_ground(&e, self.home_ned_m[2]));
                if self.landing() && (on_ground || self.blind_landed(t_us, lp)) {
                    self.disarm();
                    return say(ModeEvent::Landed);
                }
                Ok(())
            }
            FlightMode::Mission => self.fly_mission(t_us, lp, mission, say),
            FlightMode::Offboard => {
                let lost = self.commander.trajectory().is_none()
                    && self
                        .offboard
                        .is_none_or(|(_, at)| t_us.saturating_sub(at) > Self::offboard_loss_us(&nav));
                if lost {
                    let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN, lp, mission);
                    return say(ModeEvent::OffboardLost);
                }
                Ok(())
            }
            FlightMode::Hold => Ok(()),
        }
    }

    /// A landing that has pressed on the ground long enough
    /// ([`crate::land::GroundContact`]) or, without a position, has had
    /// its time ([`ModeCommander::watch_position`]). With
    /// `sensor-faults` only: otherwise never.
    fn blind_landed(&mut self, t_us: u64, lp: &Loop) -> bool {
        #[cfg(feature = "sensor-faults")]
        {
            if !self.landing() {
                self.contact.reset();
                return false;
            }
            let hover_n = lp.settings().vehicle.hover_thrust_n();
            let pressing = self.contact.step(t_us, lp.output()[0], hover_n);
            pressing || self.blind_until_us.is_some_and(|d| t_us >= d)
        }
        #[cfg(not(feature = "sensor-faults"))]
        {
            let _ = (t_us, lp);
            false
        }
    }

    /// The supervisor's tumble check (see the module's documentation):
    /// armed, tilted beyond 60° ([`crate::supervisor::tumbled`]) and not yet
    /// [`LOCKDOWN_AFTER_TAKEOFF_US`] past the take-off → disarmed, `true`.
    /// Notes the take-off, the first step in the air since arming.
    fn lockdown(&mut self, t_us: u64, lp: &Loop) -> bool {
        let Some(est) = lp.navigator().estimate() else {
            return false;
        };
        if self.takeoff_us.is_none() && est.pos_ned_m[2] < self.home_ned_m[2] - IN_AIR_M {
            self.takeoff_us = Some(t_us);
        }
        let early = self
            .takeoff_us
            .is_none_or(|t0| t_us.saturating_sub(t0) < LOCKDOWN_AFTER_TAKEOFF_US);
        if early && crate::supervisor::tumbled(&est.att) {
            self.disarm();
            return true;
        }
        false
    }

    /// Position mode's step: the joystick moves the set-point
    /// ([`joystick_velocity`]); a joystick heard and then silent for
    /// `manual_loss_s` is lost: Land, as for a lost ground station.
    fn fly_joystick<M: MissionItems + ?Sized, E>(
        &mut self,
        t_us: u64,
        dt_s: f32,
        lp: &mut Loop,
        mission: &mut M,
        say: &mut impl FnMut(ModeEvent) -> Result<(), E>,
    ) -> Result<(), E> {
        let Some(([x, y, z, r], at)) = self.manual else {
            return Ok(());
        };
        let nav = lp.settings().nav;
        if t_us.saturating_sub(at) as f32 * 1e-6 > nav.manual_loss_s {
            self.manual = None;
            if self.set_mode(FlightMode::Land, t_us, f32::NAN, lp, mission).is_ok() {
                return say(ModeEvent::JoystickLost);
            }
            return Ok(());
        }
        let mut sp = self.setpoint(t_us, lp);
        let (v, yaw_rate) = joystick_velocity(&nav, x, y, z, r, sp.yaw_rad);
        let dt = dt_s.clamp(0.0, 0.1);
        sp.pos_ned_m += v * dt;
        // Not below the ground it armed on (throttle down on the ground).
        sp.pos_ned_m[2] = sp.pos_ned_m[2].min(self.home_ned_m[2]);
        sp.yaw_rad = fc_core::control::wrap_pi(sp.yaw_rad + yaw_rate * dt);
        sp.vel_ned_mps = v;
        sp.acc_ned_mps2 = Vector3::zeros();
        sp.yaw_rate_radps = yaw_rate;
        self.commander.hold(sp);
        Ok(())
    }
}
