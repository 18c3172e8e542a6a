//! The commander: which set-point the vehicle flies and where it comes
//! from, for every protocol, as the Crazyflie's `commander.c` does it. A
//! client's stream of set-points ([`Source::Streamed`]: CRTP's generic
//! set-points) ranks above the planner's segments ([`Source::Planned`]:
//! the high-level commander's take-off, land and go-to, a hold, a failsafe
//! descent, an automatic mode's legs), and a stream is watched
//! ([`Watchdog`]): silent, it is first held level where it is, then
//! stopped. A stream hands back to the planner when its client says so
//! ([`Commander::notify_stop`]). PX4's modes ([`crate::modes`]) are a
//! source of set-points on it like any other: a mode's hold, the joystick's
//! set-point and Offboard's are held as given ([`Source::Held`]), an
//! automatic mode's legs ([`Route`]) are the planner's segments in turn
//! ([`Commander::follow`]).
//!
//! The protocols' adapters decode into its calls (CRTP's directly, MAVLink's
//! through the modes); the vehicle asks it for the set-point of every step
//! ([`Commander::setpoint_now`], [`Commander::setpoint_at`]) and hands that
//! to the flight loop, and asks for the end of a landing
//! ([`Commander::landed`]). Whether a command may take control (armed, no
//! design under way) is the vehicle's to say before it calls.

use crate::planner::{Reference, Segment};
use crate::trajectory::{Flight, Trajectories};
use fc_core::control::{Setpoint, StateEstimate};
use nalgebra::Vector3;

/// A stream's set-point older than `level_ms` is flown level and still
/// where it is; older than `stop_ms`, the stream stops (the Crazyflie's
/// `COMMANDER_WDT_TIMEOUT_STABILIZE` and `_SHUTDOWN`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Watchdog {
    /// After this long without a set-point, level and still, ms.
    pub level_ms: u64,
    /// After this long without a set-point, stopped (motors off), ms.
    pub stop_ms: u64,
}

/// Where the set-point flown comes from, lowest priority first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Priority {
    /// Nothing is flown: the motors are off.
    Idle,
    /// The planner's segment, or a set-point held as given.
    Planned,
    /// A client's stream of set-points.
    Streamed,
}

/// What the commander flies now.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Source {
    /// Nothing: no set-point, stopped, landed.
    Idle,
    /// A planner segment; `landing`: the motors stop at its end, on the
    /// ground ([`Commander::landed`]).
    Planned {
        /// The segment.
        seg: Segment,
        /// It is a landing.
        landing: bool,
    },
    /// An uploaded trajectory ([`crate::trajectory`]), under the planner,
    /// evaluated from the memory the vehicle passes.
    Trajectory {
        /// The flight.
        flight: Flight,
    },
    /// A client's set-point received at `last_us`; a velocity set-point
    /// moves its position at its velocity. `handover_us`: when control
    /// returns to the planner (the client's "notify set-point stop").
    Streamed {
        /// The set-point, moved by its velocity since it came.
        sp: Setpoint<f32>,
        /// The frame its horizontal velocity was given in.
        frame: StreamVelocity,
        /// When it came, µs.
        last_us: u64,
        /// When control returns to the planner, µs.
        handover_us: Option<u64>,
    },
    /// A set-point held as given until it is replaced (PX4's modes: a
    /// hold, the joystick's set-point, the Offboard set-point): not moved
    /// by its velocity, not watched (its timeouts are its mode's).
    Held {
        /// The set-point.
        sp: Setpoint<f32>,
    },
}

/// The frame of a streamed set-point's horizontal velocity.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StreamVelocity {
    /// North and east, as the set-point's `vel_ned_mps` gives them.
    Ned,
    /// Forward and right of the set-point's heading (m/s), turned into
    /// north and east with that heading at every step, so that a yaw rate
    /// turns the path with it (the Crazyflie's hover set-point, which its
    /// controller rotates by the heading at every step).
    Heading {
        /// Along the heading, m/s.
        forward_mps: f32,
        /// To its right, m/s.
        right_mps: f32,
    },
}

impl StreamVelocity {
    /// Sets `sp`'s north and east velocity (m/s) from `self` under `sp`'s
    /// heading (NED, clockwise from north); nothing for
    /// [`StreamVelocity::Ned`], whose velocity `sp` holds already.
    pub fn turn(self, sp: &mut Setpoint<f32>) {
        if let StreamVelocity::Heading { forward_mps, right_mps } = self {
            let (s, c) = (libm::sinf(sp.yaw_rad), libm::cosf(sp.yaw_rad));
            sp.vel_ned_mps[0] = forward_mps * c - right_mps * s;
            sp.vel_ned_mps[1] = forward_mps * s + right_mps * c;
        }
    }
}

/// Something a step of the commander did that the vehicle should say.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event {
    /// A silent stream was stopped by its watchdog: motors off.
    StreamStopped,
}

/// The set-point source in force (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Commander {
    source: Source,
    /// Counts the sources flown: a new one (a new segment, trajectory,
    /// stream or hold) is a new revision, so a preview of the one before
    /// is not taken for it ([`Commander::revision`]).
    revision: u32,
}

impl Default for Commander {
    fn default() -> Self {
        Self::new()
    }
}

impl Commander {
    /// Idle.
    pub const fn new() -> Self {
        Self {
            source: Source::Idle,
            revision: 0,
        }
    }

    /// What is flown now.
    pub fn source(&self) -> &Source {
        &self.source
    }

    /// The priority of what is flown now.
    pub fn priority(&self) -> Priority {
        match self.source {
            Source::Idle => Priority::Idle,
            Source::Planned { .. } | Source::Trajectory { .. } | Source::Held { .. } => Priority::Planned,
            Source::Streamed { .. } => Priority::Streamed,
        }
    }

    /// Nothing is flown.
    pub fn is_idle(&self) -> bool {
        self.source == Source::Idle
    }

    /// A landing segment is flown.
    pub fn is_landing(&self) -> bool {
        matches!(self.source, Source::Planned { landing: true, .. })
    }

    /// The planner's segment, if one is flown.
    pub fn segment(&self) -> Option<&Segment> {
        match &self.source {
            Source::Planned { seg, .. } => Some(seg),
            _ => None,
        }
    }

    /// The trajectory flown, if one is.
    pub fn trajectory(&self) -> Option<&Flight> {
        match &self.source {
            Source::Trajectory { flight } => Some(flight),
            _ => None,
        }
    }

    /// The stream's set-point, if a stream is flown.
    pub fn streamed(&self) -> Option<&Setpoint<f32>> {
        match &self.source {
            Source::Streamed { sp, .. } => Some(sp),
            _ => None,
        }
    }

    /// Flies `source`: a new revision.
    fn set(&mut self, source: Source) {
        self.source = source;
        self.revision = self.revision.wrapping_add(1);
    }

    /// The revision of what is flown: it changes with every new source (a
    /// stream's every packet too), never while one source is flown.
    pub fn revision(&self) -> u32 {
        self.revision
    }

    /// The reference at `t_us` (now or to come) of a source that knows its
    /// future: a segment (held at its goal after its end) or a trajectory
    /// (evaluated from `memory`); `None` for a stream, a held set-point or
    /// nothing, whose future only extrapolating it can tell.
    pub fn preview_at<M: Trajectories>(&self, t_us: u64, memory: &M) -> Option<Setpoint<f32>> {
        match &self.source {
            Source::Planned { .. } | Source::Trajectory { .. } => self.setpoint_at(t_us, memory),
            Source::Streamed { .. } | Source::Held { .. } | Source::Idle => None,
        }
    }

    /// Stops: nothing flown, motors off.
    pub fn stop(&mut self) {
        self.set(Source::Idle);
    }

    /// Flies `sp`, a client's set-point received at `now_us`, above any
    /// segment (the watchdog restarts); its horizontal velocity in `frame`
    /// (in [`StreamVelocity::Heading`], `sp`'s own horizontal velocity is
    /// replaced by it, turned with `sp`'s heading).
    pub fn stream(&mut self, mut sp: Setpoint<f32>, frame: StreamVelocity, now_us: u64) {
        frame.turn(&mut sp);
        self.set(Source::Streamed {
            sp,
            frame,
            last_us: now_us,
            handover_us: None,
        });
    }

    /// The stream's client stops streaming: `after_ms` after `now_us`,
    /// control returns to the planner, which holds where the stream was.
    /// Nothing if no stream is flown.
    pub fn notify_stop(&mut self, now_us: u64, after_ms: u32) {
        if let Source::Streamed { handover_us, .. } = &mut self.source {
            *handover_us = Some(now_us + u64::from(after_ms) * 1000);
        }
    }

    /// Flies `sp` as given until it is replaced ([`Source::Held`]).
    pub fn hold(&mut self, sp: Setpoint<f32>) {
        self.set(Source::Held { sp });
    }

    /// Flies the planner's segment `seg` (`landing`: stopped on the ground
    /// at its end).
    pub fn plan(&mut self, seg: Segment, landing: bool) {
        self.set(Source::Planned { seg, landing });
    }

    /// Flies the uploaded trajectory `flight`.
    pub fn fly_trajectory(&mut self, flight: Flight) {
        self.set(Source::Trajectory { flight });
    }

    /// Holds `from`, brought to rest over half a second, under the planner
    /// (idle if it cannot be planned).
    pub fn hold_from(&mut self, from: &Reference, t_us: u64) {
        let source = match Segment::plan(t_us, from, from.pos_ned_m, from.yaw_rad, 0.5) {
            Ok(seg) => Source::Planned { seg, landing: false },
            Err(_) => Source::Idle,
        };
        self.set(source);
    }

    /// Straight down from `here` to the frame's z = 0 (the floor of a
    /// motion-capture or Lighthouse frame) at `mps`, at least half a
    /// second, landed as a landing is (idle if it cannot be planned).
    pub fn descend(&mut self, here: &Reference, t_us: u64, mps: f32) {
        let height_m = (-here.pos_ned_m[2]).max(0.0);
        let goal = Vector3::new(here.pos_ned_m[0], here.pos_ned_m[1], 0.0);
        let dur_s = (height_m / mps).max(0.5);
        let source = match Segment::plan(t_us, here, goal, here.yaw_rad, dur_s) {
            Ok(seg) => Source::Planned { seg, landing: true },
            Err(_) => Source::Idle,
        };
        self.set(source);
    }

    /// The set-point to fly at `t_us`, `dt_s` after the last step (at most
    /// 0.1 s), `None` while idle; a stream is handed over, watched by `wd`
    /// and moved by its velocity first; a trajectory is evaluated from
    /// `memory`. The event
    /// is what the step did that the vehicle should say.
    pub fn setpoint_now<M: Trajectories>(
        &mut self,
        t_us: u64,
        dt_s: f32,
        wd: &Watchdog,
        memory: &M,
    ) -> (Option<Setpoint<f32>>, Option<Event>) {
        let mut event = None;
        if let Source::Streamed {
            sp,
            last_us,
            handover_us,
            ..
        } = self.source
        {
            let age_ms = t_us.saturating_sub(last_us) / 1000;
            if handover_us.is_some_and(|h| t_us >= h) {
                self.hold_from(&Reference::from(&sp), t_us);
            } else if age_ms > wd.stop_ms {
                self.set(Source::Idle);
                event = Some(Event::StreamStopped);
            }
        }
        if let Source::Streamed { sp, frame, last_us, .. } = &mut self.source {
            if t_us.saturating_sub(*last_us) / 1000 > wd.level_ms {
                // Level and still where it is.
                sp.vel_ned_mps = Vector3::zeros();
                sp.acc_ned_mps2 = Vector3::zeros();
                sp.yaw_rate_radps = 0.0;
                *frame = StreamVelocity::Ned;
            } else {
                // A velocity set-point moves its position; one in the
                // heading's frame turns with the heading.
                sp.pos_ned_m += sp.vel_ned_mps * dt_s;
                sp.yaw_rad += sp.yaw_rate_radps * dt_s;
                frame.turn(sp);
            }
        }
        (self.setpoint_at(t_us, memory), event)
    }

    /// The set-point flown at `t_us` as it stands (nothing advanced),
    /// `None` while idle: a segment's reference then, a stream's set-point
    /// as a reference (its jerk dropped), a held set-point as given, a
    /// trajectory's point with its jerk (evaluated from `memory`).
    pub fn setpoint_at<M: Trajectories>(&self, t_us: u64, memory: &M) -> Option<Setpoint<f32>> {
        match &self.source {
            Source::Idle => None,
            Source::Planned { seg, .. } => Some(seg.eval(t_us).setpoint()),
            Source::Trajectory { flight } => {
                let s = memory.sample(flight, t_us);
                let mut sp = s.reference.setpoint();
                sp.jerk_ned_mps3 = s.jerk_ned_mps3;
                Some(sp)
            }
            Source::Streamed { sp, .. } => Some(Reference::from(sp).setpoint()),
            Source::Held { sp } => Some(*sp),
        }
    }

    /// An automatic mode's step at `t_us`: when the segment flown has
    /// ended, `route`'s next leg is planned from its goal and flown (a
    /// landing if it is the last leg of a route that lands). Returns
    /// whether every leg is done, `None` when no segment is flown.
    pub fn follow(&mut self, route: &mut Route, t_us: u64) -> Option<bool> {
        let seg = *self.segment()?;
        if !seg.finished(t_us) {
            return Some(false);
        }
        match route.next(t_us, &seg.goal()) {
            Some((seg, landing)) => {
                self.plan(seg, landing);
                Some(false)
            }
            None => Some(true),
        }
    }

    /// What is flown at `now_us`, as a reference (a trajectory evaluated
    /// from `memory`); idle, `est` at rest (the origin without one).
    pub fn reference<M: Trajectories>(&self, now_us: u64, est: Option<&StateEstimate<f32>>, memory: &M) -> Reference {
        match &self.source {
            Source::Planned { seg, .. } => seg.eval(now_us),
            Source::Trajectory { flight } => memory.sample(flight, now_us).reference,
            Source::Streamed { sp, .. } | Source::Held { sp } => Reference::from(sp),
            Source::Idle => match est {
                Some(e) => Reference::at_rest(e.pos_ned_m, e.euler()[2]),
                None => Reference::at_rest(Vector3::zeros(), 0.0),
            },
        }
    }

    /// A landing segment has ended at `t_us` with `est` on its goal's
    /// ground ([`crate::land::on_ground`]): the commander is idle now and
    /// `true` is returned.
    pub fn landed(&mut self, t_us: u64, est: &StateEstimate<f32>) -> bool {
        match self.source {
            Source::Planned { seg, landing: true }
                if seg.finished(t_us) && crate::land::on_ground(est, seg.goal().pos_ned_m[2]) =>
            {
                self.set(Source::Idle);
                true
            }
            _ => false,
        }
    }
}

/// Duration of a rest-to-rest segment of length `d` whose peak speed is `v`
/// (the septic's peak is 35/16 · d / T), at least 0.5 s.
pub fn leg_duration_s(d_m: f32, v_mps: f32) -> f32 {
    (35.0 / 16.0 * d_m / v_mps.max(0.01)).max(0.5)
}

/// The legs of an automatic mode still to fly, each a goal (NED, m) and
/// its speed, m/s.
pub type Legs = heapless::Deque<(Vector3<f32>, f32), 3>;

/// The legs of an automatic mode still to fly after the one the
/// [`Commander`] flies ([`Commander::follow`]), at a heading held.
#[derive(Debug, Clone, Default)]
pub struct Route {
    legs: Legs,
    yaw_rad: f32,
    /// Its last leg is a landing.
    lands: bool,
}

impl Route {
    /// Nothing to fly.
    pub const fn new() -> Self {
        Self {
            legs: heapless::Deque::new(),
            yaw_rad: 0.0,
            lands: false,
        }
    }

    /// From `from` at `t_us` through `legs` in turn, holding heading `yaw`
    /// (`lands`: the last leg is a landing): the first leg's segment, and
    /// whether it is a landing, for the commander to fly
    /// ([`Commander::plan`]); `None` (nothing to fly) if no leg could be
    /// planned (a goal not finite or farther than the planner's 1 km).
    pub fn start(
        &mut self,
        t_us: u64,
        from: &Reference,
        legs: Legs,
        yaw_rad: f32,
        lands: bool,
    ) -> Option<(Segment, bool)> {
        self.legs = legs;
        self.yaw_rad = yaw_rad;
        self.lands = lands;
        self.next(t_us, from)
    }

    /// The next leg's segment from `from` at `t_us` and whether it is a
    /// landing; `None` when there is none.
    pub fn next(&mut self, t_us: u64, from: &Reference) -> Option<(Segment, bool)> {
        while let Some((goal, speed)) = self.legs.pop_front() {
            let d = (goal - from.pos_ned_m).norm();
            if let Ok(s) = Segment::plan(t_us, from, goal, self.yaw_rad, leg_duration_s(d, speed)) {
                return Some((s, self.lands && self.legs.is_empty()));
            }
        }
        None
    }

    /// No leg is left after the one flown.
    pub fn is_empty(&self) -> bool {
        self.legs.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::NoTrajectories;

    const WD: Watchdog = Watchdog {
        level_ms: 500,
        stop_ms: 2000,
    };

    fn moving() -> Setpoint<f32> {
        let mut sp = Setpoint::hold(Vector3::new(1.0, 2.0, -1.0), 0.0);
        sp.vel_ned_mps = Vector3::new(1.0, 0.0, 0.0);
        sp
    }

    #[test]
    fn a_stream_in_the_heading_frame_turns_with_its_yaw_rate_as_a_circle() {
        // 0.5 m/s forward at 1 rad/s clockwise (NED): a circle of radius
        // 0.5 m to the right. Half a turn (π s) from north at the origin
        // ends 1 m east, heading south; every point on the circle round
        // (0, 0.5).
        let mut c = Commander::new();
        let mut sp = Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0);
        sp.yaw_rate_radps = 1.0;
        let frame = StreamVelocity::Heading {
            forward_mps: 0.5,
            right_mps: 0.0,
        };
        c.stream(sp, frame, 0);
        let steps = (core::f64::consts::PI / 0.001).round() as u64;
        let mut worst = 0.0f32;
        let mut last = None;
        for k in 1..=steps {
            // A packet every 100 ms renews it, as cflib's motion commander does.
            if k % 100 == 0 {
                let mut again = *c.streamed().unwrap();
                again.yaw_rate_radps = 1.0;
                c.stream(again, frame, k * 1000);
            }
            let (now, _) = c.setpoint_now(k * 1000, 0.001, &WD, &NoTrajectories);
            let now = now.unwrap();
            let r = (now.pos_ned_m - Vector3::new(0.0, 0.5, -1.0)).norm();
            worst = worst.max((r - 0.5).abs());
            last = Some(now);
        }
        let end = last.unwrap();
        assert!(worst < 1e-3, "off the circle by {worst} m");
        assert!(
            (end.pos_ned_m - Vector3::new(0.0, 1.0, -1.0)).norm() < 2e-3,
            "{:?}",
            end.pos_ned_m
        );
        assert!((end.yaw_rad - core::f32::consts::PI).abs() < 2e-3);
        // Flying south: the velocity turned with the heading.
        assert!(
            (end.vel_ned_mps - Vector3::new(-0.5, 0.0, 0.0)).norm() < 2e-3,
            "{:?}",
            end.vel_ned_mps
        );
    }

    #[test]
    fn a_segment_is_previewed_exactly_a_stream_not_and_each_new_source_is_a_revision() {
        let mut c = Commander::new();
        let here = Reference::at_rest(Vector3::new(0.0, 0.0, -1.0), 0.0);
        let seg = Segment::plan(1_000_000, &here, Vector3::new(2.0, 1.0, -1.5), 0.0, 2.0).unwrap();
        let r0 = c.revision();
        c.plan(seg, false);
        let r1 = c.revision();
        assert_ne!(r0, r1);
        // Anywhere ahead, past its end too: the segment's own reference.
        for t in [1_000_000u64, 1_437_000, 2_999_000, 4_000_000] {
            let p = c.preview_at(t, &NoTrajectories).unwrap();
            assert_eq!(p, seg.eval(t).setpoint());
        }
        // Flying it changes no revision.
        let _ = c.setpoint_now(1_500_000, 0.001, &WD, &NoTrajectories);
        assert_eq!(c.revision(), r1);
        // A stream and a held set-point know no future.
        c.stream(moving(), StreamVelocity::Ned, 2_000_000);
        assert_ne!(c.revision(), r1);
        assert_eq!(c.preview_at(2_100_000, &NoTrajectories), None);
        c.hold(moving());
        assert_eq!(c.preview_at(2_100_000, &NoTrajectories), None);
        c.stop();
        assert_eq!(c.preview_at(2_100_000, &NoTrajectories), None);
    }

    #[test]
    fn a_stream_moves_by_its_velocity_then_levels_then_stops() {
        let mut c = Commander::new();
        assert_eq!(c.setpoint_now(0, 0.001, &WD, &NoTrajectories), (None, None));
        c.stream(moving(), StreamVelocity::Ned, 0);
        assert_eq!(c.priority(), Priority::Streamed);
        // 100 steps of 1 ms at 1 m/s north: 0.1 m.
        let mut sp = None;
        for k in 1..=100u64 {
            sp = c.setpoint_now(k * 1000, 0.001, &WD, &NoTrajectories).0;
        }
        let sp = sp.unwrap();
        assert!((sp.pos_ned_m[0] - 1.1).abs() < 1e-4, "{}", sp.pos_ned_m);
        // Silent past 500 ms: level and still, where it was.
        let (sp, ev) = c.setpoint_now(601_000, 0.001, &WD, &NoTrajectories);
        let sp = sp.unwrap();
        assert_eq!((sp.vel_ned_mps, ev), (Vector3::zeros(), None));
        let held = sp.pos_ned_m;
        let sp = c.setpoint_now(1_500_000, 0.001, &WD, &NoTrajectories).0.unwrap();
        assert_eq!(sp.pos_ned_m, held);
        // Past 2 s: stopped, said once.
        assert_eq!(
            c.setpoint_now(2_001_000, 0.001, &WD, &NoTrajectories),
            (None, Some(Event::StreamStopped))
        );
        assert!(c.is_idle());
        assert_eq!(c.setpoint_now(2_002_000, 0.001, &WD, &NoTrajectories), (None, None));
    }

    #[test]
    fn a_stream_hands_over_to_a_hold_where_it_was() {
        let mut c = Commander::new();
        c.stream(
            Setpoint::hold(Vector3::new(0.5, 0.0, -1.0), 0.3),
            StreamVelocity::Ned,
            0,
        );
        c.notify_stop(10_000, 100);
        assert_eq!(c.priority(), Priority::Streamed);
        assert!(c.setpoint_now(109_000, 0.001, &WD, &NoTrajectories).0.is_some());
        assert_eq!(c.priority(), Priority::Streamed);
        let sp = c.setpoint_now(110_000, 0.001, &WD, &NoTrajectories).0.unwrap();
        assert_eq!(c.priority(), Priority::Planned);
        assert!(!c.is_landing());
        assert!((sp.pos_ned_m - Vector3::new(0.5, 0.0, -1.0)).norm() < 1e-6);
        assert!((sp.yaw_rad - 0.3).abs() < 1e-6);
        // Nothing to hand over without a stream.
        let mut idle = Commander::new();
        idle.notify_stop(0, 0);
        assert!(idle.is_idle());
    }

    #[test]
    fn a_descent_lands_on_the_floor_then_idles() {
        let mut c = Commander::new();
        let here = Reference::at_rest(Vector3::new(1.0, 1.0, -0.5), 0.0);
        c.descend(&here, 0, 0.5);
        assert!(c.is_landing());
        // 0.5 m at 0.5 m/s: 1 s; its goal is z = 0.
        let seg = *c.segment().unwrap();
        assert_eq!(seg.goal().pos_ned_m, Vector3::new(1.0, 1.0, 0.0));
        assert!(!seg.finished(999_000) && seg.finished(1_000_000));
        let est = StateEstimate {
            pos_ned_m: Vector3::new(1.0, 1.0, -0.01),
            vel_ned_mps: Vector3::zeros(),
            att: nalgebra::Vector4::new(1.0, 0.0, 0.0, 0.0),
            rates_frd_radps: Vector3::zeros(),
        };
        // Not before the segment's end, even on the ground.
        assert!(!c.landed(500_000, &est));
        assert!(c.landed(1_000_000, &est));
        assert!(c.is_idle());
        // Idle, the reference is the estimate at rest.
        let r = c.reference(2_000_000, Some(&est), &NoTrajectories);
        assert_eq!((r.pos_ned_m, r.vel_ned_mps), (est.pos_ned_m, Vector3::zeros()));
    }

    #[test]
    fn a_route_flies_its_legs_in_turn_at_their_peak_speeds() {
        let mut c = Commander::new();
        let mut r = Route::new();
        let from = Reference::at_rest(Vector3::new(3.0, 4.0, -1.0), 0.0);
        let mut legs = Legs::new();
        legs.push_back((Vector3::new(3.0, 4.0, -2.0), 0.5)).unwrap();
        legs.push_back((Vector3::new(0.0, 0.0, -2.0), 1.0)).unwrap();
        let (seg, landing) = r.start(0, &from, legs, 0.0, true).unwrap();
        assert!(!landing && !r.is_empty());
        c.plan(seg, landing);
        let mut t = 0;
        let mut peak = [0.0f32; 2];
        let mut leg = 0;
        loop {
            let done = c.follow(&mut r, t).unwrap();
            let sp = c.setpoint_at(t, &NoTrajectories).unwrap();
            if done {
                assert!((sp.pos_ned_m - Vector3::new(0.0, 0.0, -2.0)).norm() < 1e-4);
                break;
            }
            if r.is_empty() {
                // The last leg of a route that lands is a landing.
                assert!(c.is_landing());
                leg = 1;
            }
            peak[leg] = peak[leg].max(sp.vel_ned_mps.norm());
            t += 10_000;
            assert!(t < 20_000_000, "never done");
        }
        // 1 m up at 0.5 m/s: 4.375 s; 5 m across at 1 m/s: 10.9 s.
        assert!((peak[0] - 0.5).abs() < 0.01 && (peak[1] - 1.0).abs() < 0.01, "{peak:?}");
        assert!((15_000_000..15_500_000).contains(&t), "{t}");
        // A goal 2 km away is not planned.
        let mut far = Legs::new();
        far.push_back((Vector3::new(2000.0, 0.0, -1.0), 1.0)).unwrap();
        assert!(Route::new().start(0, &from, far, 0.0, false).is_none());
        // Nothing flown, nothing followed.
        assert_eq!(Commander::new().follow(&mut r, 0), None);
    }

    #[test]
    fn a_held_set_point_is_flown_as_given() {
        let mut c = Commander::new();
        let mut sp = moving();
        sp.jerk_ned_mps3 = Vector3::new(0.0, 0.5, 0.0);
        c.hold(sp);
        assert_eq!(c.priority(), Priority::Planned);
        // Long silent, still as given: not moved, not levelled, not stopped.
        for t in [0u64, 1_000, 10_000_000] {
            assert_eq!(c.setpoint_now(t, 0.001, &WD, &NoTrajectories), (Some(sp), None));
        }
        assert_eq!(c.reference(0, None, &NoTrajectories).pos_ned_m, sp.pos_ned_m);
    }
}
