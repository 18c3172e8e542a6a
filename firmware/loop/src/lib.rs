//! The flight controller's loop logic, independent of hardware: frames in,
//! controller step, frames out, failsafe. The binary (and the SIL's framed
//! and TCP targets) drive it through hal-shim's `ByteLink` and `CycleClock`.
//!
//! Failure behaviour: corrupt, truncated, oversized or undecodable frames are
//! dropped and counted; sensor frames whose sequence number or (in lockstep)
//! time does not increase are not flown, counted, and answered with the
//! held output (a lockstep client must not block); NaN/∞ or a non-unit
//! attitude is rejected (the reply repeats the current output). No valid
//! sensor frame for the failsafe timeout (parameter `FS_TIMEOUT_MS`) → failsafe: level (zero torques)
//! and a gentle descent (thrust below hover); the first valid frame
//! afterwards resumes control. Every loop is bounded; nothing allocates or
//! blocks.
//!
//! Time ([`TimeBase`]): in lockstep (the SIL, QEMU, simulators) the clock is
//! the simulated time each sensor frame carries, so a host that is slow in
//! wall time causes nothing, and a gap in *simulated* time longer than the
//! timeout is a failsafe episode; free-running (a vehicle) uses the caller's
//! real clock. Resuming after a gap keeps the controller's estimates (the
//! MPC's disturbance estimate, its warm start) and drops only what links one
//! step to the one before (`Controller::resume`).
//!
//! Sensor flights: every `Imu` frame (1 kHz) steps the estimator and is
//! answered; the controller runs only when its [`schedule::Schedule`] is
//! due (every 2 ms for PD/LQR, 5 ms for the fast MPC), and between its runs
//! the answers repeat the output it gave last.

#![cfg_attr(not(test), no_std)]
#![deny(missing_docs)]
#![forbid(unsafe_code)]

pub mod arming;
pub mod baro;
pub mod client;
pub mod commander;
pub mod health;
pub mod land;
pub mod modes;
pub mod nav;
pub mod params;
pub mod planner;
pub mod power;
pub mod preview;
pub mod schedule;
pub mod supervisor;
pub mod telemetry;
pub mod trajectory;

mod flight_loop;
mod jobs;
mod wire;

pub use flight_loop::FlightLoop;
pub use jobs::{
    apply_param, fallback_controller, install, redesign, run_job, select, stabilize, start_front_end, Actuation,
    ControlJob, Design, HoldsLoop, Job, LoopOf, Step,
};
pub use wire::{fix_from_wire, fix_to_wire, param_answer, setpoint_from_wire, setpoint_to_wire, Framed};

use fc_core::control::{
    AnyController, ControlError, ControlOutput, Controller, ControllerSpec, Family, PdEuler, PdEulerGains,
    ReferenceMode, Setpoint, StateEstimate,
};
use fc_core::estimate::{Fix, ImuSample};
use fc_core::model::airframe::Mixer;
use fc_core::model::{AttitudeForm, Input, QuatState, VehicleParams};
use fc_proto::{
    encode, Counters, FrameDecoder, FrameError, FromFc, ToFc, WireFix, WireSetpoint, MAX_FRAME, PROTOCOL_VERSION,
};
use hal_shim::{ByteLink, CycleClock};
use nalgebra::{Vector3, Vector4};
use nav::{NavMode, Navigator};

/// Loop settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FcConfig {
    /// Control period the controllers are designed for, s (PD/LQR; the MPC
    /// presets fix their own).
    pub control_period_s: f64,
    /// Most link reads per `service` call (bounds the work per call).
    pub max_reads_per_service: usize,
    /// The clock the failsafe timer runs on.
    pub time_base: TimeBase,
    /// Lockstep: the largest step of simulated time between two accepted
    /// sensor frames, µs. A frame whose time jumps further is an absurd
    /// timestamp: not flown and counted as out of order, so that it cannot
    /// become the clock (every later frame would then be "in the past").
    /// A simulation that really jumps that far starts a new session (`Hello`).
    pub max_time_step_us: u64,
}

/// The clock of the flight loop's failsafe timer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TimeBase {
    /// Lockstep simulation (SIL, QEMU, a simulator driving the loop): the
    /// time is the simulated time `t_us` of the sensor frames, as PX4's
    /// lockstep takes the simulator's timestamps. Wall time that passes
    /// without frames is not a timeout (a host that stops, stops time); a
    /// frame whose time jumps past the timeout since the last valid one
    /// ends a failsafe episode (counted) and resumes control; a frame whose
    /// time does not increase is not flown and is counted as out of order.
    Lockstep,
    /// Free-running (a vehicle): the caller's real clock, the `now_us` of
    /// [`FlightLoop::service`] and [`Loop::check_timeout`]; the
    /// frames' `t_us` is not used.
    FreeRunning,
}

impl Default for FcConfig {
    fn default() -> Self {
        Self {
            control_period_s: 0.002,
            max_reads_per_service: 16,
            time_base: TimeBase::Lockstep,
            max_time_step_us: 10_000_000,
        }
    }
}

/// Bounds of a plausible sensor state (see `FlightLoop`'s frame checks).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plausible {
    /// Largest position coordinate, m (NED).
    pub position_m: f32,
    /// Largest velocity component, m/s: also the speed at which the
    /// position may move between two frames.
    pub speed_mps: f32,
    /// Largest body rate, rad/s (a BMI088 gyro saturates at 2000 °/s ≈ 35 rad/s).
    pub rate_radps: f32,
    /// Position change allowed on top of `speed × time` between two frames, m
    /// (a position fix that corrects a drifted estimate).
    pub jump_m: f32,
}

/// The bounds in force.
pub const PLAUSIBLE: Plausible = Plausible {
    position_m: 1.0e4,
    speed_mps: 100.0,
    rate_radps: 50.0,
    jump_m: 1.0,
};

/// The controller a flight controller runs from boot until a `Select`
/// arrives: the quaternion LQR, reference fed forward.
pub const BOOT_CONTROLLER: ControllerSpec = ControllerSpec::new(Family::Lqr, AttitudeForm::Quaternion);

/// The controller that flies when neither a new selection nor the previous
/// one can be designed: the tuned Euler PD (no design step, cannot fail).
pub const FALLBACK_CONTROLLER: ControllerSpec = ControllerSpec::new(Family::Pd, AttitudeForm::Euler);

/// Where the flight loop's answers go: encoded into frames on a
/// [`ByteLink`] ([`Framed`]), or to a front end that translates them.
pub trait Outbox {
    /// What sending can fail with.
    type Error;
    /// Sends one message.
    fn send(&mut self, msg: &FromFc) -> Result<(), Self::Error>;
}

/// The flight loop without its controller: the link's decoder and
/// counters, the session, the parameters, the estimator and its schedule,
/// the failsafe, the output held.
///
/// [`FlightLoop`] is a `Loop` and its controller, stepped in one call. An
/// image that runs the estimator and the controller at two interrupt
/// priorities keeps them apart: the `Loop` is shared (the sample's
/// interrupt steps the estimator in it, [`Loop::on_frame`]), the controller
/// belongs to the controller's task alone, which runs the [`Job`]s the
/// `Loop` hands it ([`run_job`]) and touches the `Loop` only for short,
/// bounded moments, through an RTIC [`Mutex`]. Both ways run the same
/// code, in the same order, so their outputs are identical.
#[derive(Debug)]
pub struct Loop {
    cfg: FcConfig,
    /// The parameters (vehicle, controller, failsafe; the motor settings
    /// are a front end's): `settings.vehicle` is what the controllers are
    /// designed for.
    settings: params::Settings,
    /// What the controller was built from (rebuilt when a new selection fails).
    spec: ControllerSpec,
    /// The controller's period, µs (cached at each design: the estimator's
    /// schedule and the failsafe timer need it without the controller).
    period_us: u64,
    /// The controller takes a set-point preview (an MPC).
    takes_preview: bool,
    /// Preview set-points received since the controller last ran, applied
    /// before its next step ([`Loop::apply_previews`]).
    previews: preview::PreviewSlots,
    /// The commander's preview, given a few points a step ([`Loop::preview_from`]).
    feed: preview::PreviewFeed,
    /// The age of the preview to tell the controller after the slots, s.
    preview_age: Option<f32>,
    sp: Setpoint<f32>,
    decoder: FrameDecoder<MAX_FRAME>,
    counters: Counters,
    session: bool,
    last_seq: Option<u32>,
    /// Time of the last accepted sensor frame (lockstep), µs.
    last_t_us: Option<u64>,
    /// Time of the last valid controller step, µs, on the time base's clock.
    last_valid_us: Option<u64>,
    /// Position of the last flown sensor frame (NED, m) and its time, µs.
    last_pos: Option<(Vector3<f32>, u64)>,
    failsafe: bool,
    u: Input<f32>,
    selections: u32,
    /// The estimator of `Imu` steps (sensor flights).
    nav: Navigator,
    /// A barometer as the estimator's height fix (its reference is the
    /// session's).
    baro: baro::Barometer,
    /// The estimator's failsafe flew the last `Imu` step.
    nav_failsafe: bool,
    /// When the controller runs under the `Imu` steps.
    schedule: schedule::Schedule,
    /// Time of the controller's last update, µs, on the time base's clock
    /// (its next update is told the interval: [`Controller::elapsed`]).
    last_control_us: Option<u64>,
    /// The mixer `settings` give, once a protocol front end started the
    /// loop ([`start_front_end`]; [`power`]).
    mixer: Option<Mixer<f32>>,
}

/// A [`Loop`] reached directly: the [`Mutex`] of a caller that owns it
/// (in-process; RTIC's own proxies are the other kind).
pub use rtic_core::Exclusive;
/// Access to a shared [`Loop`] for a bounded moment (RTIC's resource lock).
pub use rtic_core::Mutex;

/// The answers to one step: `Actuator`, `Telemetry` and, for an `Imu`
/// step, `Nav` and `NavBias`.
pub type Answers = heapless::Vec<FromFc, 4>;

impl Loop {
    /// The loop with `settings`, nothing designed yet: its controller is
    /// the tuned Euler PD ([`FALLBACK_CONTROLLER`], which has no period of
    /// its own) until a design ([`FlightLoop::start`]). Built in place
    /// (inlined), so that no stack copy of it is made.
    #[inline(always)]
    pub fn unstarted_with(cfg: FcConfig, settings: params::Settings) -> Self {
        Self {
            cfg,
            settings,
            spec: FALLBACK_CONTROLLER,
            period_us: schedule::period_us(cfg.control_period_s),
            takes_preview: false,
            previews: preview::PreviewSlots::new(),
            feed: preview::PreviewFeed::new(),
            preview_age: None,
            sp: Setpoint::hold(Vector3::new(0.0, 0.0, -1.0), 0.0),
            decoder: FrameDecoder::new(),
            counters: Counters::default(),
            session: false,
            last_seq: None,
            last_t_us: None,
            last_valid_us: None,
            last_pos: None,
            failsafe: false,
            u: Vector4::zeros(),
            selections: 0,
            nav: Navigator::bmi088(),
            baro: baro::Barometer::new(),
            nav_failsafe: false,
            schedule: schedule::Schedule::new(),
            last_control_us: None,
            mixer: None,
        }
    }

    /// The estimator of sensor flights.
    pub fn navigator(&self) -> &Navigator {
        &self.nav
    }

    /// The estimator of sensor flights, to give it a simulator's true
    /// state ([`Navigator::set_truth`]; host builds with `truth-state`).
    #[cfg(feature = "truth-state")]
    pub fn navigator_mut(&mut self) -> &mut Navigator {
        &mut self.nav
    }

    /// The inputs to apply now `[U1 N, U2 N, U3 N, U4 N·m]`.
    pub fn output(&self) -> Input<f32> {
        self.u
    }

    /// Failsafe active.
    pub fn failsafe(&self) -> bool {
        self.failsafe
    }

    /// Frame and error counters.
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Controller selections that succeeded since boot.
    pub fn selections(&self) -> u32 {
        self.selections
    }

    /// The handshake has completed.
    pub fn session_open(&self) -> bool {
        self.session
    }

    /// The vehicle the controllers are designed for.
    pub fn vehicle(&self) -> &VehicleParams<f32> {
        &self.settings.vehicle
    }

    /// The controller flying (or the one that flies once designed).
    pub fn spec(&self) -> ControllerSpec {
        self.spec
    }

    /// The loop's settings.
    pub fn config(&self) -> &FcConfig {
        &self.cfg
    }

    /// The set-point being flown (the estimator's failsafe may override it).
    pub fn setpoint(&self) -> &Setpoint<f32> {
        &self.sp
    }

    /// Opens a session, as an accepted `Hello` does: a new time line (a
    /// simulation restarts at t = 0), the estimator starts over. Out of
    /// line: its callers (a `Hello`, a host's restart, an estimator reset)
    /// are rare, and each inlined copy is ~350 B of flash.
    #[inline(never)]
    pub fn open_session(&mut self) {
        self.session = true;
        self.last_seq = None;
        self.last_t_us = None;
        self.last_valid_us = None;
        self.last_pos = None;
        self.nav.reset();
        self.baro.reset();
        self.nav_failsafe = false;
        self.schedule.reset();
        self.last_control_us = None;
    }

    /// Restarts the estimator at a client's request (a Crazyflie's
    /// `kalman.resetEstimation`): a new time line ([`Loop::open_session`]),
    /// refused ([`params::Refusal::Armed`]) while `motors_turn` (the front
    /// end's gate, as for a parameter write): nothing could hold the
    /// vehicle while its estimator aligns again.
    pub fn reset_estimation(&mut self, motors_turn: bool) -> Result<(), params::Refusal> {
        if motors_turn {
            return Err(params::Refusal::Armed);
        }
        self.open_session();
        Ok(())
    }

    /// Flies `sp` from now on, as a `Setpoint` message does; a set-point
    /// with NaN/∞ is refused (counted) and `false` returned.
    pub fn set_setpoint(&mut self, sp: &Setpoint<f32>) -> bool {
        match setpoint_from_wire(&setpoint_to_wire(sp)) {
            Some(sp) => {
                self.sp = sp;
                true
            }
            None => {
                self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
                false
            }
        }
    }

    /// Queues a position fix for the next `Imu` step, as a `Fix` message does.
    pub fn push_fix(&mut self, fix: &Fix) {
        self.nav.push_fix(fix);
    }

    /// A barometer's altitude `alt_m` (m above sea level) read at `t_us`,
    /// fused as a height fix before the next `Imu` step
    /// ([`baro::Barometer`]: at most every [`baro::PERIOD_US`], its first
    /// reading of the session referenced to the estimated height then).
    /// `true` if it was fused; a reading that is not a measurement, or one
    /// before the estimator has a position, is not.
    pub fn push_baro(&mut self, t_us: u64, alt_m: f32) -> bool {
        let est_down_m = self.nav.estimate().map(|e| e.pos_ned_m[2]);
        match self.baro.fix(t_us, alt_m, est_down_m) {
            Some(fix) => {
                self.nav.push_fix(&fix);
                true
            }
            None => false,
        }
    }

    /// The parameters in force.
    pub fn settings(&self) -> &params::Settings {
        &self.settings
    }

    /// Puts `next` (checked by [`params::write`]) in force; a started
    /// front end's mixer follows it (`MOT_FRAME` changes it without a
    /// design).
    fn set_settings(&mut self, next: params::Settings) {
        self.settings = next;
        if self.mixer.is_some() {
            // A checked write mixes; were it not to, the old mixer stays.
            if let Ok(m) = next.mixer() {
                self.mixer = Some(m);
            }
        }
    }

    /// Writes `value` to parameter `index`: the whole settings checked; a
    /// change that needs no design is taken at once (the mixer the check
    /// built follows it), and `Ok(None)` returned, as for a value already
    /// in force; a change of the vehicle, the controller or its gains and
    /// weights needs a re-design, whose settings are returned for the
    /// controller's side ([`redesign`]), nothing taken yet.
    ///
    /// The one write rule of every protocol: a re-design is refused
    /// ([`params::Refusal::Armed`]) while `motors_turn`, the front end's
    /// supervisor gate, the `fly` it gives [`Loop::power`] (PX4's modes:
    /// armed, the motors idle on the ground; the Crazyflie's: armed and
    /// flying a set-point; our protocol: its session has had a step). A
    /// design takes many steps' time, and no controller flies meanwhile.
    /// A refusal leaves everything as it was.
    ///
    /// It runs under a protocol's lock of the vehicle, a sample that
    /// comes ready meanwhile waiting: the settings are copied once, to be
    /// checked, and once more when taken.
    pub fn write_param(
        &mut self,
        index: usize,
        value: f32,
        motors_turn: bool,
    ) -> Result<Option<params::Settings>, params::Refusal> {
        let mut next = self.settings;
        let mixer = params::write_into(&mut next, index, value)?;
        // `index` is known (`write_into` refused it otherwise). A
        // parameter writes only its own field: its value says whether
        // anything changed, its flag whether the change re-designs.
        let p = &params::PARAMS[index];
        if (p.get)(&next).to_bits() == (p.get)(&self.settings).to_bits() {
            return Ok(None);
        }
        match (p.redesign, motors_turn) {
            (false, _) => {
                self.settings = next;
                if self.mixer.is_some() {
                    self.mixer = Some(mixer);
                }
                Ok(None)
            }
            (true, false) => Ok(Some(next)),
            (true, true) => Err(params::Refusal::Armed),
        }
    }

    /// An `Imu` message's estimator half ([`Loop::on_imu`]) as a front end
    /// that speaks another protocol takes it: `None` (counted as
    /// unexpected) before the session opens, else the step for the
    /// controller's half ([`stabilize`]).
    pub fn imu_job<C: CycleClock>(
        &mut self,
        seq: u32,
        t_us: u64,
        imu: &ImuSample,
        clock: &C,
        now_us: u64,
    ) -> Option<Step> {
        if !self.session {
            self.counters.unexpected = self.counters.unexpected.wrapping_add(1);
            return None;
        }
        self.counters.ok = self.counters.ok.wrapping_add(1);
        Some(self.on_imu(seq, t_us, imu, clock, now_us))
    }

    /// A design's inputs under the settings in force.
    pub fn design(&self) -> Design {
        Design {
            vehicle: self.settings.vehicle,
            tuning: self.settings.tuning,
            control_period_s: self.cfg.control_period_s,
            running: self.spec,
        }
    }

    /// Records a design: `requested` was asked for (and `ok` if it was
    /// built), `flying` flies now on `ctrl`. Previews held for the
    /// controller it replaced are dropped.
    pub fn installed(
        &mut self,
        requested: ControllerSpec,
        ok: bool,
        flying: ControllerSpec,
        ctrl: &AnyController<f32>,
    ) {
        self.spec = flying;
        if ok {
            self.settings.controller = requested;
        }
        self.period_us = schedule::period_us(ctrl.period_s().unwrap_or(self.cfg.control_period_s));
        self.takes_preview = ctrl.preview_request().is_some();
        self.previews.clear();
        self.feed.configure(ctrl.preview_request(), self.period_us);
        self.preview_age = None;
    }

    /// The controller's step `step`, when it is due, previews what
    /// `commander` flies ([`commander::Commander::preview_at`], a trajectory
    /// evaluated from `memory`; a new source known by its
    /// [`commander::Commander::revision`]). A few points a step
    /// ([`preview::PreviewFeed`]); none while the estimator's failsafe
    /// flies its own set-point (previewed along itself).
    pub fn preview_from<M: trajectory::Trajectories>(
        &mut self,
        step: &Step,
        commander: &commander::Commander,
        memory: &M,
    ) {
        let Some(job) = step.control.as_ref() else {
            return;
        };
        if job.preview_along {
            self.feed.drop_preview();
            self.preview_age = None;
            return;
        }
        self.preview_age = self
            .feed
            .step(job.now_us, commander.revision(), &mut self.previews, |t| {
                commander.preview_at(t, memory)
            });
    }

    /// Hands the previews received since the controller's last step to
    /// `ctrl` (counted if it refuses one it takes).
    pub fn apply_previews(&mut self, ctrl: &mut AnyController<f32>) {
        let mut dropped = false;
        for (k, sp) in self.previews.drain() {
            if k == 0 {
                // The feed's preview moves on; refused only when the
                // controller dropped it (a reset).
                dropped |= ctrl.roll_preview(&sp).is_err();
            } else if ctrl.set_preview(k, &sp).is_err() && self.takes_preview {
                self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
            }
        }
        if let Some(age_s) = self.preview_age.take() {
            dropped |= ctrl.age_preview(age_s).is_err();
        }
        if dropped {
            // It extrapolates this step, and the feed fills it anew.
            self.feed.drop_preview();
        }
    }

    /// Applies the failsafe timer at real time `now_us` (free-running only:
    /// in lockstep the timer runs on the sensor frames' time, and wall time
    /// is not a timeout).
    pub fn check_timeout(&mut self, now_us: u64) {
        if self.cfg.time_base == TimeBase::FreeRunning {
            self.timeout_at(now_us);
        }
    }

    /// How often the running controller runs, µs (its own period, or the
    /// loop's control period): on the sample grid, at the first sample at
    /// or after each multiple ([`schedule::Schedule`]).
    pub fn controller_period_us(&self) -> u64 {
        self.period_us()
    }

    /// The running controller's period, µs.
    fn period_us(&self) -> u64 {
        self.period_us
    }

    /// Enters the failsafe if the last valid step is more than the timeout
    /// (at least two controller periods) before `now_us`, on the time base's clock.
    fn timeout_at(&mut self, now_us: u64) {
        // Never less than two periods of the running controller (the thesis
        // MPC steps at 4 Hz: its frames are 250 ms apart by design).
        let timeout = (u64::from(self.settings.failsafe_timeout_ms) * 1000).max(self.period_us().saturating_mul(2));
        if let Some(t) = self.last_valid_us {
            if now_us.saturating_sub(t) > timeout && !self.failsafe {
                self.failsafe = true;
                self.counters.failsafe_entries = self.counters.failsafe_entries.wrapping_add(1);
                self.u = Vector4::new(
                    self.settings.failsafe_descent * self.settings.vehicle.hover_thrust_n(),
                    0.0,
                    0.0,
                    0.0,
                );
            }
        }
    }

    /// A state a multirotor can be in, reached from the last flown one:
    /// within [`PLAUSIBLE`]'s bounds, and moved no further than its top
    /// speed allows in the time since (plus a jump allowance). A finite but
    /// absurd frame (a 100 m jump, rates of 1e30 rad/s) is refused here
    /// rather than flown: one such frame loses a 4 Hz MPC its vehicle.
    fn plausible(&self, est: &StateEstimate<f32>, now_us: u64) -> bool {
        let p = &PLAUSIBLE;
        let within = est.pos_ned_m.amax() <= p.position_m
            && est.vel_ned_mps.amax() <= p.speed_mps
            && est.rates_frd_radps.amax() <= p.rate_radps;
        let reachable = self.last_pos.is_none_or(|(last, t)| {
            let dt_s = now_us.saturating_sub(t) as f32 * 1e-6;
            (est.pos_ned_m - last).amax() <= p.speed_mps * dt_s + p.jump_m
        });
        within && reachable
    }

    /// Longer since the last valid step than a controller integrates over
    /// ([`fc_core::control::plausible_step`]: 20 ms, or one and a half
    /// periods of a slower controller): this step does not follow that one
    /// (frames were missing or invalid).
    fn gap_since_last_step(&self, now_us: u64) -> bool {
        let period_s = self.period_us() as f64 * 1e-6;
        self.last_valid_us
            .is_some_and(|t| !fc_core::control::plausible_step(now_us.saturating_sub(t) as f64 * 1e-6, period_s))
    }

    /// Whether the controller's step at `now_us` resumes (valid data again
    /// after the failsafe or, in lockstep, a gap: the controller keeps its
    /// estimates and forgets only the step before, see
    /// `Controller::resume`); the failsafe ends here.
    fn take_resume(&mut self, now_us: u64) -> bool {
        let lockstep = self.cfg.time_base == TimeBase::Lockstep;
        let resume = self.failsafe || (lockstep && self.gap_since_last_step(now_us));
        if resume {
            self.failsafe = false;
        }
        resume
    }

    /// The controller's step at `now_us` from `est` to `sp`: told the
    /// measured interval since its last one (a 2 ms simulator under a 1 ms
    /// controller, a late sample), or resumed when that interval is a gap.
    fn control_job(
        &mut self,
        now_us: u64,
        est: StateEstimate<f32>,
        sp: Setpoint<f32>,
        resume: bool,
        preview_along: bool,
    ) -> ControlJob {
        let interval_us = self.last_control_us.map(|t| now_us.saturating_sub(t));
        self.last_control_us = Some(now_us);
        ControlJob {
            now_us,
            est,
            sp,
            resume,
            preview_along,
            interval_us,
            period_s: self.period_us() as f64 * 1e-6,
        }
    }

    /// One IMU step's estimator half: the estimator integrates the sample
    /// (with the fixes received since the last step); when the controller
    /// is due, the step it is to fly — the mission's setpoint, or the
    /// estimator's failsafe hold-and-descend; while aligning, hover thrust
    /// and no torque. Every step is answered (the output held since the
    /// controller last ran) with a `Nav` message added ([`Loop::finish`]).
    pub fn on_imu<C: CycleClock>(&mut self, seq: u32, t_us: u64, imu: &ImuSample, clock: &C, now_us: u64) -> Step {
        let Some(now) = self.accept_step(seq, t_us, now_us) else {
            return Step {
                seq,
                t0: None,
                nav: false,
                control: None,
            };
        };
        let t0 = clock.now();
        let stepped = self.nav.step(now, imu, &[]);
        // Asked at every step, so that the grid follows the steps' times.
        let due = self.schedule.due(now, self.period_us());
        let mut control = None;
        match (stepped, self.nav.estimate()) {
            (Ok(mode @ (NavMode::Navigating | NavMode::Failsafe)), Some(est)) => {
                self.nav_failsafe = mode == NavMode::Failsafe;
                if due {
                    let resume = self.take_resume(now);
                    let sp = self.nav.setpoint(now, &self.sp);
                    control = Some(self.control_job(now, est, sp, resume, self.nav_failsafe));
                }
            }
            (Ok(_), _) => {
                // Aligning at rest: hold hover thrust, no torque.
                self.u = Vector4::new(self.settings.vehicle.hover_thrust_n(), 0.0, 0.0, 0.0);
                self.nav_failsafe = false;
                self.failsafe = false;
                self.last_valid_us = Some(now);
            }
            (Err(_), _) => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
        }
        Step {
            seq,
            t0: Some(t0),
            nav: true,
            control,
        }
    }

    /// Records the controller's result for `step` (`None`: it did not run)
    /// and returns the step's answers on our protocol: the output now held,
    /// the telemetry, and the estimator's state for an `Imu` step.
    pub fn finish<C: CycleClock>(
        &mut self,
        step: &Step,
        result: Option<Result<ControlOutput<f32>, ControlError>>,
        clock: &C,
    ) -> Answers {
        let a = self.record(step, result, clock);
        self.answers(step, &a)
    }

    /// Records the controller's result for `step` (`None`: it did not run;
    /// an error is counted and the last output held) and returns what the
    /// step gives the motors' side.
    // Inlined (as `answers`): the step's two halves out of line cost the
    // image step ≈ 1 400 instructions in the budget harness, the
    // estimator's task included (the inlining around it changed).
    #[inline(always)]
    pub fn record<C: CycleClock>(
        &mut self,
        step: &Step,
        result: Option<Result<ControlOutput<f32>, ControlError>>,
        clock: &C,
    ) -> Actuation {
        let mut iterations = 0u16;
        if let (Some(job), Some(r)) = (&step.control, result) {
            match r {
                Ok(o) => {
                    self.u = o.u;
                    iterations = o.status.iterations;
                    self.last_valid_us = Some(job.now_us);
                }
                Err(_) => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
            }
        }
        Actuation {
            u: [self.u[0], self.u[1], self.u[2], self.u[3]],
            failsafe: self.failsafe || self.nav_failsafe,
            cycles: step.t0.map_or(0, |t0| clock.since(t0)),
            qp_iterations: iterations,
        }
    }

    /// `step`'s answers on our protocol, from what it gave
    /// ([`Loop::record`]).
    #[inline(always)]
    pub fn answers(&self, step: &Step, a: &Actuation) -> Answers {
        let mut answers = Answers::new();
        // Four pushes into a Vec of four: none fails.
        let _ = answers.push(FromFc::Actuator {
            seq: step.seq,
            u: a.u,
            failsafe: a.failsafe,
        });
        let _ = answers.push(FromFc::Telemetry {
            seq: step.seq,
            cycles: a.cycles,
            qp_iterations: a.qp_iterations,
            counters: self.counters,
            failsafe: a.failsafe,
        });
        if step.nav {
            let (nav, bias) = self.nav_messages(step.seq);
            let _ = answers.push(nav);
            let _ = answers.push(bias);
        }
        answers
    }
}

#[cfg(test)]
mod tests;
