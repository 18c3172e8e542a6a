//! The commander a client drives directly, by set-points it streams and
//! segments it plans, under the supervisor's arming (the Crazyflie's
//! `commander.c` with its `supervisor.c`): [`ClientCommander`]. PX4's
//! modes, which a ground station commands by mode, are the other source of
//! set-points on the same [`Commander`] ([`crate::modes::ModeCommander`]).
//!
//! It decides what a client's command may do, for any protocol that
//! speaks this way (fc-crtp decodes CRTP into its calls and says its
//! refusals):
//!
//! - **Arming** is the one check ([`Arming::arm`]); arming or disarming
//!   stops whatever was flown, so nothing from before flies on.
//! - **An uploaded trajectory** ([`crate::trajectory`]) is written into
//!   the vehicle's trajectory memory, defined by id and started like a
//!   segment; while one flies, the memory refuses writes, so what flies is
//!   never changed under it.
//! - **A streamed set-point** flies only while armed. It takes control from
//!   the planner or from idle, as any command does ([`ClientCommander::plan`]).
//! - **Taking control** is refused while disarmed or while a controller
//!   design is under way (no controller flies then); from idle, the
//!   controller's state is to be forgotten first ([`Takeover::Reset`]: no
//!   state wound up on the ground flies).
//! - **The emergency stop** stops and locks until a restart; a **recovery**
//!   clears a tumble, unless locked or flying.
//! - **Each step** the supervisor checks the IMU's sample and, after the
//!   estimator, starts the failsafe descent, latches a tumble or ends a
//!   landing ([`Supervisor`]).
//!
//! The motors turn while it is [`ClientCommander::flying`]: armed and the
//! commander not idle, as a Crazyflie's do.

use crate::arming::{ArmRefusal, Arming, ArmingState};
use crate::commander::{Commander, Event, Priority, Source, StreamVelocity, Watchdog};
use crate::planner::{Reference, Segment};
use crate::supervisor::{ImuCounters, ImuOutcome, Supervised, Supervisor};
use crate::trajectory::{Definition, Flight, StartOptions, TrajectoryError, TrajectoryMemory};
use fc_core::control::{Setpoint, StateEstimate};
use fc_core::estimate::ImuSample;

/// Why a client's command was not flown.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandRefusal {
    /// The vehicle is not armed.
    NotArmed,
    /// A controller design is under way: no controller flies until it is done.
    Designing,
    /// The trajectory cannot be flown (see the error).
    Trajectory(TrajectoryError),
}

impl core::fmt::Display for CommandRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CommandRefusal::NotArmed => f.write_str("not armed"),
            CommandRefusal::Designing => f.write_str("controller design under way"),
            CommandRefusal::Trajectory(e) => e.fmt(f),
        }
    }
}

/// What a command that took control asks of the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Takeover {
    /// Fly on: the controller was flying already.
    Continue,
    /// Forget the controller's state before its first step (control taken
    /// from idle: `Controller::reset`, no new design).
    Reset,
}

/// Arming, the commander, the supervisor and the trajectory memory of a
/// vehicle a client flies (see the module's documentation).
#[derive(Debug, Clone, Copy, Default)]
pub struct ClientCommander {
    arming: Arming,
    commander: Commander,
    supervisor: Supervisor,
    memory: TrajectoryMemory,
    /// The last step's reference: its time, the source it came from (as it
    /// stood then) and the reference, so that a command in the same step
    /// does not evaluate it again ([`ClientCommander::reference`]).
    flown: Option<(u64, Source, Reference)>,
}

impl ClientCommander {
    /// Disarmed, idle, no sample seen.
    pub const fn new() -> Self {
        Self {
            arming: Arming::new(),
            commander: Commander::new(),
            supervisor: Supervisor::new(),
            memory: TrajectoryMemory::new(),
            flown: None,
        }
    }

    /// Armed, and the supervisor's latches (the lock, the tumble).
    pub fn arming(&self) -> &Arming {
        &self.arming
    }

    /// The set-point flown and its source.
    pub fn commander(&self) -> &Commander {
        &self.commander
    }

    /// Armed.
    pub fn armed(&self) -> bool {
        self.arming.armed()
    }

    /// The motors turn: armed and flying a set-point
    /// ([`crate::supervisor::flying`]).
    pub fn flying(&self) -> bool {
        crate::supervisor::flying(&self.arming, &self.commander)
    }

    /// The supervisor's "can fly": the arming check on `s` would pass, the
    /// vehicle's start apart (the Crazyflie's `supervisorCanFly`).
    pub fn can_fly(&self, s: &ArmingState) -> bool {
        let started = ArmingState { started: true, ..*s };
        self.arming.may_arm(&started).is_ok()
    }

    /// Arms if the one check passes on `s`: `Ok(true)` armed now (the
    /// commander stopped: nothing from before flies), `Ok(false)` armed
    /// already.
    pub fn arm(&mut self, s: &ArmingState) -> Result<bool, ArmRefusal> {
        let armed = self.arming.arm(s, || Ok(()))?.is_some();
        if armed {
            self.commander.stop();
        }
        Ok(armed)
    }

    /// Disarmed, the commander stopped.
    pub fn disarm(&mut self) {
        self.arming.disarm();
        self.commander.stop();
    }

    /// The emergency stop: the commander stopped, disarmed and locked
    /// until a restart.
    pub fn emergency_stop(&mut self) {
        self.commander.stop();
        self.arming.lock();
    }

    /// Clears a tumble, unless locked or flying; whether it did.
    pub fn recover(&mut self) -> bool {
        let flying = self.flying();
        self.arming.recover(flying)
    }

    /// Motors off: nothing flown (a client's stop).
    pub fn stop(&mut self) {
        self.commander.stop();
    }

    /// A client's stream hands back to the planner after `after_ms`
    /// ([`Commander::notify_stop`]).
    pub fn notify_stop(&mut self, now_us: u64, after_ms: u32) {
        self.commander.notify_stop(now_us, after_ms);
    }

    /// Whether a command may take control now (`designing`: a controller
    /// design is under way), and what it asks of the controller.
    fn take_control(&self, designing: bool) -> Result<Takeover, CommandRefusal> {
        if !self.arming.armed() {
            return Err(CommandRefusal::NotArmed);
        }
        if designing {
            return Err(CommandRefusal::Designing);
        }
        Ok(if self.commander.is_idle() {
            Takeover::Reset
        } else {
            Takeover::Continue
        })
    }

    /// Flies `sp`, a client's streamed set-point with its horizontal
    /// velocity in `frame` ([`Commander::stream`]), from `now_us`: refused
    /// while disarmed, and when control cannot be taken from anything but
    /// a stream (a stream already flying goes on).
    pub fn stream(
        &mut self,
        sp: Setpoint<f32>,
        frame: StreamVelocity,
        now_us: u64,
        designing: bool,
    ) -> Result<Takeover, CommandRefusal> {
        // A stream already flying goes on; anything else takes control.
        let takeover = if self.flying() && self.commander.priority() == Priority::Streamed {
            Takeover::Continue
        } else {
            self.take_control(designing)?
        };
        self.commander.stream(sp, frame, now_us);
        Ok(takeover)
    }

    /// Flies the planner's segment `seg` (`landing`: the motors stop on
    /// the ground at its end), when control can be taken.
    pub fn plan(&mut self, seg: Segment, landing: bool, designing: bool) -> Result<Takeover, CommandRefusal> {
        let takeover = self.take_control(designing)?;
        self.commander.plan(seg, landing);
        Ok(takeover)
    }

    /// Writes `data` into the trajectory memory from byte `addr`: refused
    /// while a trajectory flies ([`TrajectoryError::Flying`]) or past the
    /// memory's end, and then nothing is written.
    pub fn write_trajectory_memory(&mut self, addr: u32, data: &[u8]) -> Result<(), TrajectoryError> {
        if self.commander.trajectory().is_some() {
            return Err(TrajectoryError::Flying);
        }
        self.memory.write(addr, data)
    }

    /// The trajectory memory.
    pub fn trajectory_memory(&self) -> &TrajectoryMemory {
        &self.memory
    }

    /// Defines trajectory `id` as `pieces` pieces from byte `offset` of the
    /// memory, after checking them ([`TrajectoryMemory::define`]).
    pub fn define_trajectory(&mut self, id: u8, offset: u32, pieces: u8) -> Result<(), TrajectoryError> {
        self.memory.define(id, Definition::new(offset, pieces)?)
    }

    /// Flies trajectory `id` from `now_us` with `options` (a relative one
    /// from `from`, the reference flown), when control can be taken and the
    /// trajectory starts ([`Flight::start`]).
    pub fn start_trajectory(
        &mut self,
        id: u8,
        options: StartOptions,
        from: &Reference,
        now_us: u64,
        designing: bool,
    ) -> Result<Takeover, CommandRefusal> {
        let takeover = self.take_control(designing)?;
        let flight = Flight::start(&self.memory, id, now_us, options, from).map_err(CommandRefusal::Trajectory)?;
        self.commander.fly_trajectory(flight);
        Ok(takeover)
    }

    /// The IMU sample to step at `t_us` ([`Supervisor::take`]).
    pub fn take_sample(&mut self, t_us: u64, s: Option<&ImuSample>) -> (Option<ImuSample>, ImuOutcome) {
        self.supervisor.take(t_us, s)
    }

    /// A new time line (a host that started again).
    pub fn restart(&mut self) {
        self.supervisor.restart();
    }

    /// The set-point to fly at `t_us`, `dt_s` after the last step, with the
    /// stream's watchdog `wd` ([`Commander::setpoint_now`]).
    pub fn setpoint_now(&mut self, t_us: u64, dt_s: f32, wd: &Watchdog) -> (Option<Setpoint<f32>>, Option<Event>) {
        let (sp, event) = self.commander.setpoint_now(t_us, dt_s, wd, &self.memory);
        self.flown = sp.map(|sp| (t_us, *self.commander.source(), Reference::from(&sp)));
        (sp, event)
    }

    /// The supervisor's checks of the step at `t_us`, after its estimator
    /// (`est`; [`Supervisor::step`]).
    pub fn supervise(&mut self, t_us: u64, est: Option<&StateEstimate<f32>>) -> Supervised {
        self.supervisor
            .step(t_us, &mut self.arming, &mut self.commander, est, &self.memory)
    }

    /// What is flown at `now_us`, as a reference (`est` at rest when idle).
    /// The last step's, if `now_us` is its time and the source has not
    /// changed since: the same numbers, not evaluated again.
    pub fn reference(&self, now_us: u64, est: Option<&StateEstimate<f32>>) -> Reference {
        match self.flown(now_us) {
            Some(r) => r,
            None => self.commander.reference(now_us, est, &self.memory),
        }
    }

    /// The last step's reference, if `now_us` is its time and the source
    /// has not changed since ([`ClientCommander::reference`] without an
    /// estimate to make).
    pub fn flown(&self, now_us: u64) -> Option<Reference> {
        match &self.flown {
            Some((t, source, r)) if *t == now_us && source == self.commander.source() => Some(*r),
            _ => None,
        }
    }

    /// The IMU samples that were not good, by kind.
    pub fn imu_counters(&self) -> ImuCounters {
        self.supervisor.imu_counters()
    }

    /// A failsafe descent is under way (the IMU went silent in flight).
    pub fn failsafe(&self) -> bool {
        self.supervisor.failsafe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::arming::tests::ready;
    use crate::commander::Watchdog;
    use nalgebra::Vector3;

    fn sp() -> Setpoint<f32> {
        Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0)
    }

    fn seg() -> Segment {
        let from = Reference {
            pos_ned_m: Vector3::zeros(),
            vel_ned_mps: Vector3::zeros(),
            acc_ned_mps2: Vector3::zeros(),
            yaw_rad: 0.0,
            yaw_rate_radps: 0.0,
        };
        Segment::plan(0, &from, Vector3::new(0.0, 0.0, -1.0), 0.0, 2.0).expect("a 1 m climb in 2 s plans")
    }

    /// Disarmed, nothing takes control, and nothing is flown; the refusal
    /// is typed.
    #[test]
    fn a_disarmed_vehicle_flies_no_command() {
        let mut c = ClientCommander::new();
        assert_eq!(
            c.stream(sp(), StreamVelocity::Ned, 0, false),
            Err(CommandRefusal::NotArmed)
        );
        assert_eq!(c.plan(seg(), false, false), Err(CommandRefusal::NotArmed));
        assert!(c.commander().is_idle() && !c.flying());
        assert_eq!(CommandRefusal::NotArmed.to_string(), "not armed");
    }

    /// Control taken from idle asks for the controller's reset; a stream
    /// already flying goes on; the planner under a stream is taken over.
    #[test]
    fn taking_control_from_idle_resets_the_controller_once() {
        let mut c = ClientCommander::new();
        assert_eq!(c.arm(&ready()), Ok(true));
        assert_eq!(c.arm(&ready()), Ok(false), "armed already");
        assert!(!c.flying(), "armed, nothing flown: motors off");
        assert_eq!(c.stream(sp(), StreamVelocity::Ned, 0, false), Ok(Takeover::Reset));
        assert!(c.flying());
        assert_eq!(c.stream(sp(), StreamVelocity::Ned, 10, false), Ok(Takeover::Continue));
        assert_eq!(c.plan(seg(), false, false), Ok(Takeover::Continue));
        assert_eq!(c.commander().priority(), Priority::Planned);
        assert_eq!(c.stream(sp(), StreamVelocity::Ned, 20, false), Ok(Takeover::Continue));
    }

    /// While a controller is designed, nothing takes control from idle or
    /// from the planner, and says so.
    #[test]
    fn nothing_takes_control_while_a_controller_is_designed() {
        let mut c = ClientCommander::new();
        assert_eq!(c.arm(&ready()), Ok(true));
        assert_eq!(
            c.stream(sp(), StreamVelocity::Ned, 0, true),
            Err(CommandRefusal::Designing)
        );
        assert_eq!(c.plan(seg(), false, true), Err(CommandRefusal::Designing));
        assert!(c.commander().is_idle());
        assert_eq!(CommandRefusal::Designing.to_string(), "controller design under way");
    }

    /// Arming and disarming stop what was flown; the emergency stop locks
    /// until a restart, and a locked or flying vehicle does not recover.
    #[test]
    fn arming_the_stop_and_recovery_end_what_was_flown() {
        let mut c = ClientCommander::new();
        assert_eq!(c.arm(&ready()), Ok(true));
        assert_eq!(c.stream(sp(), StreamVelocity::Ned, 0, false), Ok(Takeover::Reset));
        assert!(!c.recover(), "flying: no recovery");
        c.disarm();
        assert!(!c.armed() && c.commander().is_idle());
        assert!(c.recover(), "on the ground, unlocked");
        assert_eq!(c.arm(&ready()), Ok(true));
        assert_eq!(c.stream(sp(), StreamVelocity::Ned, 0, false), Ok(Takeover::Reset));
        c.emergency_stop();
        assert!(!c.armed() && c.commander().is_idle() && c.arming().locked());
        assert!(!c.recover(), "locked");
        assert!(!c.can_fly(&ready()));
        assert_eq!(c.arm(&ready()), Err(ArmRefusal::Locked));
    }

    /// A trajectory flies only armed; while it flies the memory refuses
    /// writes and what flies is unchanged; a segment (a landing, a go_to)
    /// takes over from where the trajectory is, and the memory takes
    /// writes again.
    #[test]
    fn a_trajectory_flies_armed_and_its_memory_is_not_written_under_it() {
        use crate::trajectory::{Piece, StartOptions, PIECE_BYTES};
        let mut c = ClientCommander::new();
        // North at 1 m/s for 2 s, 1 m up.
        let mut north = [0.0; 8];
        north[1] = 1.0;
        let mut down = [0.0; 8];
        down[0] = -1.0;
        let piece = Piece {
            poly: [north, [0.0; 8], down, [0.0; 8]],
            duration_s: 2.0,
        };
        c.write_trajectory_memory(0, &piece.to_bytes()).unwrap();
        c.define_trajectory(1, 0, 1).unwrap();
        let go = StartOptions {
            time_scale: 1.0,
            reversed: false,
            relative_position: false,
            relative_yaw: false,
        };
        let here = Reference::at_rest(Vector3::zeros(), 0.0);
        assert_eq!(
            c.start_trajectory(1, go, &here, 0, false),
            Err(CommandRefusal::NotArmed)
        );
        assert_eq!(c.arm(&ready()), Ok(true));
        assert_eq!(
            c.start_trajectory(2, go, &here, 0, false),
            Err(CommandRefusal::Trajectory(TrajectoryError::Undefined))
        );
        assert_eq!(c.start_trajectory(1, go, &here, 0, false), Ok(Takeover::Reset));
        assert!(c.flying());
        let wd = Watchdog {
            level_ms: 500,
            stop_ms: 2000,
        };
        let (flown, _) = c.setpoint_now(1_000_000, 0.001, &wd);
        let flown = flown.unwrap();
        assert_eq!(flown.pos_ned_m, Vector3::new(1.0, 0.0, -1.0));
        assert_eq!(flown.vel_ned_mps, Vector3::new(1.0, 0.0, 0.0));
        // The step's reference, as the commander evaluates it.
        let evaluated = c.commander().reference(1_000_000, None, c.trajectory_memory());
        assert_eq!(c.reference(1_000_000, None), evaluated);
        assert_eq!(evaluated.vel_ned_mps, flown.vel_ned_mps);
        let bytes = *c.trajectory_memory();
        assert_eq!(c.write_trajectory_memory(0, &[0xff; 24]), Err(TrajectoryError::Flying));
        assert_eq!(c.trajectory_memory(), &bytes, "nothing written");
        assert_eq!(
            c.setpoint_now(1_000_000, 0.0, &wd).0.unwrap().pos_ned_m,
            flown.pos_ned_m
        );
        // A landing from where the trajectory is, at its speed.
        let from = c.reference(1_500_000, None);
        assert_eq!(from.pos_ned_m, Vector3::new(1.5, 0.0, -1.0));
        let land = Segment::plan(1_500_000, &from, Vector3::new(1.5, 0.0, 0.0), 0.0, 2.0).unwrap();
        assert_eq!(c.plan(land, true, false), Ok(Takeover::Continue));
        assert!(c.commander().trajectory().is_none());
        assert_eq!(c.reference(1_500_000, None).vel_ned_mps, Vector3::new(1.0, 0.0, 0.0));
        c.write_trajectory_memory(PIECE_BYTES as u32, &[0; 24]).unwrap();
    }
}
