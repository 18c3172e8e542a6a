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

pub mod baro;
pub mod nav;
pub mod params;
pub mod planner;
pub mod schedule;

use fc_core::control::{
    AnyController, ControlError, ControlOutput, Controller, ControllerSpec, Family, PdEuler, PdEulerGains,
    ReferenceMode, Setpoint, StateEstimate,
};
use fc_core::estimate::{Fix, ImuSample};
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
    /// [`FlightCore::service`] and [`Loop::check_timeout`]; the
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

/// Bounds of a plausible sensor state (see `FlightCore`'s frame checks).
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

/// Our own protocol's frames on a byte link.
pub struct Framed<'a, L>(pub &'a mut L);

impl<L: ByteLink> Outbox for Framed<'_, L> {
    type Error = L::Error;
    fn send(&mut self, msg: &FromFc) -> Result<(), L::Error> {
        let mut out = [0u8; MAX_FRAME];
        match encode(msg, &mut out) {
            Ok(n) => self.0.write_all(&out[..n]),
            // Our own messages always fit MAX_FRAME (tested); nothing to send otherwise.
            Err(_) => Ok(()),
        }
    }
}

/// A controllers' setpoint as sent on the wire.
pub fn setpoint_to_wire(sp: &Setpoint<f32>) -> WireSetpoint {
    WireSetpoint {
        pos: sp.pos_ned_m.into(),
        vel: sp.vel_ned_mps.into(),
        acc: sp.acc_ned_mps2.into(),
        jerk: sp.jerk_ned_mps3.into(),
        yaw: sp.yaw_rad,
        yaw_rate: sp.yaw_rate_radps,
    }
}

/// A wire setpoint as the controllers' type; `None` if any value is not finite.
pub fn setpoint_from_wire(w: &WireSetpoint) -> Option<Setpoint<f32>> {
    let sp = Setpoint {
        pos_ned_m: Vector3::from(w.pos),
        vel_ned_mps: Vector3::from(w.vel),
        acc_ned_mps2: Vector3::from(w.acc),
        jerk_ned_mps3: Vector3::from(w.jerk),
        yaw_rad: w.yaw,
        yaw_rate_radps: w.yaw_rate,
    };
    sp.is_valid().then_some(sp)
}

/// The flight controller's state between steps.
///
/// One lockstep step over a host link (the SIL's `--target framed` does the
/// same; the image does it over USART1):
///
/// ```
/// use fc_loop::{FcConfig, FlightCore};
/// use fc_proto::{encode, FrameDecoder, FromFc, ToFc, MAX_FRAME, PROTOCOL_VERSION};
/// use hal_shim::host::{LoopbackLink, MonotonicClock};
///
/// let mut fc = FlightCore::new(FcConfig::default())?; // quaternion LQR, motors off
/// let (mut link, clock) = (LoopbackLink::default(), MonotonicClock::default());
/// let send = |link: &mut LoopbackLink, m: &ToFc| {
///     let mut frame = [0u8; MAX_FRAME];
///     let n = encode(m, &mut frame).expect("our messages fit a frame");
///     link.rx.extend(&frame[..n]);
/// };
/// send(&mut link, &ToFc::Hello { version: PROTOCOL_VERSION });
/// // The vehicle hovers at its boot setpoint, 1 m up: state
/// // [x y z (m, NED), ẋ ẏ ż (m/s), q0 q1 q2 q3, p q r (rad/s, FRD)].
/// let mut state = [0.0f32; 13];
/// (state[2], state[6]) = (-1.0, 1.0);
/// send(&mut link, &ToFc::Sensor { seq: 1, t_us: 2_000, state });
/// fc.service(&mut link, &clock, 2_000)?;
///
/// let mut rx = FrameDecoder::<MAX_FRAME>::new();
/// let replies: Vec<FromFc> = link.tx.iter().filter_map(|&b| rx.push(b)).collect::<Result<_, _>>()?;
/// assert!(matches!(replies[0], FromFc::HelloAck { accepted: true, .. }));
/// // Step 1's inputs: hover thrust (0.65 kg × 9.81 m/s²), no torque, not the failsafe.
/// let FromFc::Actuator { seq: 1, u, failsafe: false } = replies[1] else { panic!("{replies:?}") };
/// assert!((u[0] - 0.65 * 9.81).abs() < 1e-3 && u[1..].iter().all(|v| v.abs() < 1e-4));
/// assert!(matches!(replies[2], FromFc::Telemetry { .. }));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Debug)]
pub struct FlightCore {
    /// Everything but the controller.
    lp: Loop,
    /// The running controller.
    ctrl: AnyController<f32>,
}

/// The flight loop without its controller: the link's decoder and
/// counters, the session, the parameters, the estimator and its schedule,
/// the failsafe, the output held.
///
/// [`FlightCore`] is a `Loop` and its controller, stepped in one call. An
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
    previews: [Option<Setpoint<f32>>; PREVIEW_SLOTS],
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
    /// The estimator's failsafe flew the last `Imu` step.
    nav_failsafe: bool,
    /// When the controller runs under the `Imu` steps.
    schedule: schedule::Schedule,
    /// Time of the controller's last update, µs, on the time base's clock
    /// (its next update is told the interval: [`Controller::elapsed`]).
    last_control_us: Option<u64>,
}

/// Our protocol's answer to a parameter request (`ParamRead`, `ParamSet`)
/// under `settings`: parameter `index`'s id and value in force, and why a
/// write was refused (`refusal`; 0 when it was not, `Unknown`'s code for an
/// index past the table). For a board whose simulator writes its
/// parameters as [`FlightCore`] answers them (`firmware-crtp`).
pub fn param_answer(settings: &params::Settings, index: u16, refusal: Option<params::Refusal>) -> FromFc {
    let p = params::PARAMS.get(usize::from(index));
    let mut id = [0u8; 16];
    if let Some(p) = p {
        // Ids are at most 16 characters (MAVLink's `param_id`); cut, not panic.
        let n = p.id.len().min(id.len());
        id[..n].copy_from_slice(&p.id.as_bytes()[..n]);
    }
    FromFc::Param {
        index,
        count: params::PARAMS.len() as u16,
        id,
        value: p.map_or(f32::NAN, |p| (p.get)(settings)),
        refusal: match (p, refusal) {
            (None, _) => params::Refusal::Unknown.code(),
            (_, Some(r)) => r.code(),
            (_, None) => 0,
        },
    }
}

/// A wire fix as the estimator's type.
pub fn fix_from_wire(w: &WireFix) -> Fix {
    Fix {
        age_s: w.age_us as f32 * 1e-6,
        pos_ned_m: w.pos.map(Vector3::from),
        pos_sigma_m: Vector3::from(w.pos_sigma),
        vel_ned_mps: w.vel.map(Vector3::from),
        vel_sigma_mps: w.vel_sigma,
        yaw_rad: w.yaw,
        yaw_sigma_rad: w.yaw_sigma,
        alt_m: w.alt,
        alt_sigma_m: w.alt_sigma,
    }
}

/// An estimator's fix on the wire (ages rounded to the µs).
pub fn fix_to_wire(f: &Fix) -> WireFix {
    WireFix {
        age_us: (f.age_s.max(0.0) * 1e6 + 0.5) as u32,
        pos: f.pos_ned_m.map(Into::into),
        pos_sigma: f.pos_sigma_m.into(),
        vel: f.vel_ned_mps.map(Into::into),
        vel_sigma: f.vel_sigma_mps,
        yaw: f.yaw_rad,
        yaw_sigma: f.yaw_sigma_rad,
        alt: f.alt_m,
        alt_sigma: f.alt_sigma_m,
    }
}

/// Preview set-points a [`Loop`] holds between two controller steps, by
/// index: 0..=N for the MPCs' horizon N (they take 1..=N).
pub const PREVIEW_SLOTS: usize = fc_core::control::regulation::HORIZON + 1;

/// Work for the controller's task: everything that needs the controller.
#[derive(Debug, Clone, Copy)]
pub enum Job {
    /// A sensor or IMU step: fly it if `control` says so, then answer it.
    Step(Step),
    /// Design this controller in place of the running one (`Select`).
    Select(ControllerSpec),
    /// Write a parameter (`ParamSet`); a re-design only if `allow_redesign`.
    Param {
        /// Index in [`params::PARAMS`].
        index: u16,
        /// Its new value.
        value: f32,
        /// The vehicle is not flying (no step of the session yet).
        allow_redesign: bool,
    },
}

/// A step the estimator (or a state frame) has taken: what its answer needs.
#[derive(Debug, Clone, Copy)]
pub struct Step {
    /// The frame's sequence number.
    pub seq: u32,
    /// The cycle clock when the step began (`None`: it was not flown; the
    /// answer reports 0 cycles).
    pub t0: Option<u32>,
    /// The answer carries the estimator's `Nav` and `NavBias` messages.
    pub nav: bool,
    /// The controller's step, when it is due.
    pub control: Option<ControlJob>,
}

/// One controller step: its inputs, as the loop prepared them.
#[derive(Debug, Clone, Copy)]
pub struct ControlJob {
    /// Time of the step, µs, on the time base's clock.
    pub now_us: u64,
    /// The state to fly from (NED, body FRD).
    pub est: StateEstimate<f32>,
    /// The set-point to fly to.
    pub sp: Setpoint<f32>,
    /// After a gap or the failsafe: the controller forgets the step before.
    pub resume: bool,
    /// The estimator's failsafe flies `sp`: the preview follows it.
    pub preview_along: bool,
    /// Time since the controller's last step, µs (none before the first).
    pub interval_us: Option<u64>,
    /// The controller's period, s.
    pub period_s: f64,
}

impl ControlJob {
    /// Runs the step on `ctrl`: resume, preview, the measured interval,
    /// then the update.
    pub fn fly(&self, ctrl: &mut AnyController<f32>) -> Result<ControlOutput<f32>, ControlError> {
        if self.resume {
            ctrl.resume();
        }
        if self.preview_along {
            Navigator::preview_along(ctrl, &self.sp);
        }
        if let Some(dt) = self.interval_us {
            fc_core::control::tell_interval(ctrl, dt, self.period_s);
        }
        ctrl.update(&self.est, &self.sp)
    }
}

/// A design's inputs, copied out of the [`Loop`] so that the design (which
/// takes milliseconds to tens of them) runs without it.
#[derive(Debug, Clone, Copy)]
pub struct Design {
    /// The vehicle designed for.
    pub vehicle: VehicleParams<f32>,
    /// Gains and weights.
    pub tuning: fc_core::control::Tuning,
    /// The loop's control period, s (PD, LQR).
    pub control_period_s: f64,
    /// The controller flying now: designed again if the new one fails.
    pub running: ControllerSpec,
}

impl Design {
    /// Designs `spec` into `ctrl`. On failure the running controller is
    /// designed again (the slot no longer holds it), or the fallback PD if
    /// even that fails. Returns the result and what flies afterwards.
    pub fn run(
        &self,
        ctrl: &mut AnyController<f32>,
        spec: ControllerSpec,
    ) -> (Result<(), ControlError>, ControllerSpec) {
        let build = |s: ControllerSpec, c: &mut AnyController<f32>| {
            s.build_in(c, self.vehicle, self.control_period_s, None, &self.tuning)
        };
        match build(spec, ctrl) {
            Ok(()) => (Ok(()), spec),
            Err(e) if build(self.running, ctrl).is_ok() => (Err(e), self.running),
            Err(e) => {
                // PD designs cannot fail: nothing to check.
                let _ = build(FALLBACK_CONTROLLER, ctrl);
                (Err(e), FALLBACK_CONTROLLER)
            }
        }
    }
}

/// What a parameter write does ([`Loop::plan_param`]).
#[derive(Debug, Clone, Copy)]
pub enum ParamPlan {
    /// The value in force: nothing.
    Unchanged,
    /// New settings, no design.
    Set(params::Settings),
    /// New settings whose controller is designed first.
    Redesign(params::Settings),
}

/// A [`Loop`] reached directly: the [`Mutex`] of a caller that owns it
/// (in-process; RTIC's own proxies are the other kind).
pub use rtic_core::Exclusive;
/// Access to a shared [`Loop`] for a bounded moment (RTIC's resource lock).
pub use rtic_core::Mutex;

/// The answers to one step: `Actuator`, `Telemetry` and, for an `Imu`
/// step, `Nav` and `NavBias`.
pub type Answers = heapless::Vec<FromFc, 4>;

/// Runs `job` on the controller's side: the controller `ctrl`, the shared
/// loop `lp` locked only to read the step's previews and to record its
/// result, the answers to `out`. [`FlightCore`] calls it directly; an image
/// whose controller runs in its own task calls it there.
pub fn run_job<M: Mutex<T = Loop>, O: Outbox, C: CycleClock>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    job: Job,
    out: &mut O,
    clock: &C,
) -> Result<(), O::Error> {
    match job {
        Job::Step(step) => {
            let result = step.control.map(|c| {
                lp.lock(|l| l.apply_previews(ctrl));
                c.fly(ctrl)
            });
            let answers = lp.lock(|l| l.finish(&step, result, clock));
            answers.iter().try_for_each(|m| out.send(m))
        }
        Job::Select(spec) => {
            if select(lp, ctrl, spec).is_err() {
                lp.lock(|l| l.counters.invalid_values = l.counters.invalid_values.wrapping_add(1));
            }
            Ok(())
        }
        Job::Param {
            index,
            value,
            allow_redesign,
        } => {
            let r = lp
                .lock(|l| l.plan_param(usize::from(index), value, allow_redesign))
                .and_then(|plan| apply_plan(lp, ctrl, plan));
            let answer = lp.lock(|l| {
                if r.is_err() {
                    l.counters.invalid_values = l.counters.invalid_values.wrapping_add(1);
                }
                param_answer(&l.settings, index, r.err())
            });
            out.send(&answer)
        }
    }
}

/// Designs `spec` on `ctrl` in place of the running controller, the loop
/// unlocked while it runs; on failure the running one is designed again, or
/// the fallback PD if even that fails ([`Design::run`]), and the error is
/// returned. The loop records what flies ([`Loop::installed`]).
pub fn install<M: Mutex<T = Loop>>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    spec: ControllerSpec,
) -> Result<(), ControlError> {
    let (r, flying) = lp.lock(|l| l.design()).run(ctrl, spec);
    lp.lock(|l| l.installed(spec, r.is_ok(), flying, ctrl));
    r
}

/// Selects `spec` (as a `Select` does): [`install`], counted as a
/// selection when it was built; on failure the running controller keeps
/// flying and the error is returned.
pub fn select<M: Mutex<T = Loop>>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    spec: ControllerSpec,
) -> Result<(), ControlError> {
    install(lp, ctrl, spec)?;
    lp.lock(|l| l.selections = l.selections.wrapping_add(1));
    Ok(())
}

/// Starts a protocol front end's loop `lp` with its controller `ctrl`
/// ([`FlightCore::start_front_end`]): the settings checked, their
/// controller designed in place, the session opened (set-points may come
/// before samples); returns the mixer the settings give for its motors.
pub fn start_front_end(
    lp: &mut Loop,
    ctrl: &mut AnyController<f32>,
) -> Result<fc_core::model::airframe::Mixer<f32>, params::Refusal> {
    lp.settings.check()?;
    let spec = lp.settings.controller;
    install(&mut Exclusive(&mut *lp), ctrl, spec).map_err(params::Refusal::Design)?;
    lp.open_session();
    lp.settings.mixer()
}

/// The controller a loop flies before its first design: the tuned Euler
/// PD ([`FALLBACK_CONTROLLER`], which needs no design) for `vehicle`.
pub fn fallback_controller(vehicle: VehicleParams<f32>) -> AnyController<f32> {
    AnyController::PdEuler(PdEuler::new(vehicle, PdEulerGains::tuned(), ReferenceMode::Feedforward))
}

/// Carries out a parameter write's plan: a re-design runs on `ctrl` with
/// the loop unlocked; a refusal leaves everything as it was.
pub fn apply_plan<M: Mutex<T = Loop>>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    plan: ParamPlan,
) -> Result<(), params::Refusal> {
    match plan {
        ParamPlan::Unchanged => Ok(()),
        ParamPlan::Set(next) => {
            lp.lock(|l| l.settings = next);
            Ok(())
        }
        ParamPlan::Redesign(next) => {
            let (old, design) = lp.lock(|l| (l.settings, l.design()));
            let (r, flying) = Design {
                vehicle: next.vehicle,
                tuning: next.tuning,
                ..design
            }
            .run(ctrl, next.controller);
            match r {
                Ok(()) => {
                    lp.lock(|l| {
                        l.installed(next.controller, true, flying, ctrl);
                        if next.controller != old.controller {
                            l.selections = l.selections.wrapping_add(1);
                        }
                        l.settings = next;
                    });
                    Ok(())
                }
                Err(e) => {
                    // Back to the old settings, and their controller (it
                    // was designed from them before).
                    let (r_old, flying) = Design {
                        running: flying,
                        ..design
                    }
                    .run(ctrl, old.controller);
                    lp.lock(|l| l.installed(old.controller, r_old.is_ok(), flying, ctrl));
                    Err(params::Refusal::Design(e))
                }
            }
        }
    }
}

impl core::ops::Deref for FlightCore {
    type Target = Loop;
    fn deref(&self) -> &Loop {
        &self.lp
    }
}

impl core::ops::DerefMut for FlightCore {
    fn deref_mut(&mut self) -> &mut Loop {
        &mut self.lp
    }
}

impl FlightCore {
    /// A flight controller running the quaternion LQR until told otherwise,
    /// motors off until the first valid sensor frame:
    /// [`FlightCore::unstarted`] then [`FlightCore::start`].
    pub fn new(cfg: FcConfig) -> Result<Self, ControlError> {
        let mut me = Self::unstarted(cfg);
        me.start()?;
        Ok(me)
    }

    /// The flight loop with nothing designed yet: it flies the tuned Euler
    /// PD (which needs no design) until [`FlightCore::start`] designs the
    /// boot controller in place. The firmware constructs it this way, in
    /// its static home, so that the boot design does not run beneath a
    /// stack copy of the whole loop (the controller is ≈ 7 KiB).
    pub fn unstarted(cfg: FcConfig) -> Self {
        Self::unstarted_with(cfg, params::Settings::os4())
    }

    /// The flight loop with `settings` (the parameters: vehicle,
    /// controller, failsafe), nothing designed yet: [`FlightCore::start`]
    /// checks the settings and designs their controller for their vehicle,
    /// in place.
    pub fn unstarted_with(cfg: FcConfig, settings: params::Settings) -> Self {
        Self {
            ctrl: fallback_controller(settings.vehicle),
            lp: Loop::unstarted_with(cfg, settings),
        }
    }

    /// The loop and its controller apart: for an image that runs them in
    /// two tasks ([`run_job`]).
    pub fn split(&mut self) -> (&mut Loop, &mut AnyController<f32>) {
        (&mut self.lp, &mut self.ctrl)
    }

    /// Designs the settings' controller (by default the boot controller,
    /// [`BOOT_CONTROLLER`]) in place for their vehicle. On error (settings
    /// [`params::Settings::check`] refuses, or a failed design) the loop
    /// keeps flying the fallback PD.
    pub fn start(&mut self) -> Result<(), ControlError> {
        self.lp.settings.check().map_err(|_| ControlError::InvalidParameter)?;
        // Unstarted, the previous controller is the fallback PD.
        self.install(self.lp.settings.controller)
    }

    /// For a protocol front end (MAVLink, CRTP): checks the settings,
    /// designs their controller in place ([`FlightCore::start`]), opens the
    /// session (set-points may come before samples) and returns the mixer
    /// the settings give for the front end's motors.
    pub fn start_front_end(&mut self) -> Result<fc_core::model::airframe::Mixer<f32>, params::Refusal> {
        start_front_end(&mut self.lp, &mut self.ctrl)
    }

    /// One IMU sample `imu` taken at `t_us`, as an `Imu` message of
    /// sequence `seq` is handled (answers to `out`): for front ends that
    /// need nothing else of the protocol (the image links only this path).
    pub fn imu_step<O: Outbox, C: CycleClock>(
        &mut self,
        seq: u32,
        t_us: u64,
        imu: &ImuSample,
        out: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<(), O::Error> {
        match self.lp.imu_job(seq, t_us, imu, clock, now_us) {
            Some(job) => self.run(job, out, clock),
            None => Ok(()),
        }
    }

    /// Sets parameter `index` ([`params::PARAMS`]) to `value`: the whole
    /// settings checked; a change of the vehicle, the controller or its
    /// gains and weights re-designs it, which only `allow_redesign` permits
    /// (a front end says whether the vehicle is disarmed). A refusal leaves
    /// everything as it was.
    pub fn apply_param(&mut self, index: usize, value: f32, allow_redesign: bool) -> Result<(), params::Refusal> {
        let plan = self.lp.plan_param(index, value, allow_redesign)?;
        apply_plan(&mut Exclusive(&mut self.lp), &mut self.ctrl, plan)
    }

    /// Designs `spec` in place of the running controller (as a `Select`
    /// does); on failure the running one keeps flying and the error is
    /// returned. Not in flight: a design takes milliseconds to tens of them.
    pub fn try_select(&mut self, spec: ControllerSpec) -> Result<(), ControlError> {
        select(&mut Exclusive(&mut self.lp), &mut self.ctrl, spec)
    }

    /// Reads what the link has (bounded), handles every complete frame,
    /// writes replies, then applies the failsafe timer at time `now_us`.
    pub fn service<L: ByteLink, C: CycleClock>(
        &mut self,
        link: &mut L,
        clock: &C,
        now_us: u64,
    ) -> Result<(), L::Error> {
        let mut buf = [0u8; 64];
        for _ in 0..self.lp.cfg.max_reads_per_service {
            let n = link.read(&mut buf)?;
            if n == 0 {
                break;
            }
            for &b in &buf[..n.min(buf.len())] {
                if let Some(frame) = self.lp.decoder.push::<ToFc>(b) {
                    let job = self.lp.on_frame(frame, &mut Framed(link), clock, now_us)?;
                    if let Some(job) = job {
                        self.run(job, &mut Framed(link), clock)?;
                    }
                }
            }
        }
        self.lp.check_timeout(now_us);
        Ok(())
    }

    /// Handles one decoded message as if it had arrived on the link at
    /// `now_us`, its answers to `out`: the entry of front ends that speak
    /// another protocol (MAVLink) and translate into this one.
    pub fn handle_message<O: Outbox, C: CycleClock>(
        &mut self,
        msg: ToFc,
        out: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<(), O::Error> {
        match self.lp.on_message(msg, out, clock, now_us)? {
            Some(job) => self.run(job, out, clock),
            None => Ok(()),
        }
    }

    /// Runs a job of the loop on this controller.
    fn run<O: Outbox, C: CycleClock>(&mut self, job: Job, out: &mut O, clock: &C) -> Result<(), O::Error> {
        run_job(&mut Exclusive(&mut self.lp), &mut self.ctrl, job, out, clock)
    }

    /// [`install`] on this loop's controller.
    fn install(&mut self, spec: ControllerSpec) -> Result<(), ControlError> {
        install(&mut Exclusive(&mut self.lp), &mut self.ctrl, spec)
    }
}

impl Loop {
    /// The loop with `settings`, nothing designed yet: its controller is
    /// the tuned Euler PD ([`FALLBACK_CONTROLLER`], which has no period of
    /// its own) until a design ([`FlightCore::start`]). Built in place
    /// (inlined), so that no stack copy of it is made.
    #[inline(always)]
    pub fn unstarted_with(cfg: FcConfig, settings: params::Settings) -> Self {
        Self {
            cfg,
            settings,
            spec: FALLBACK_CONTROLLER,
            period_us: schedule::period_us(cfg.control_period_s),
            takes_preview: false,
            previews: [None; PREVIEW_SLOTS],
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
            nav_failsafe: false,
            schedule: schedule::Schedule::new(),
            last_control_us: None,
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
    /// simulation restarts at t = 0), the estimator starts over.
    pub fn open_session(&mut self) {
        self.session = true;
        self.last_seq = None;
        self.last_t_us = None;
        self.last_valid_us = None;
        self.last_pos = None;
        self.nav.reset();
        self.nav_failsafe = false;
        self.schedule.reset();
        self.last_control_us = None;
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

    /// The parameters in force.
    pub fn settings(&self) -> &params::Settings {
        &self.settings
    }

    /// What writing `value` to parameter `index` does: the whole settings
    /// checked; a change of the vehicle, the controller or its gains and
    /// weights needs a re-design, which only `allow_redesign` permits.
    pub fn plan_param(&self, index: usize, value: f32, allow_redesign: bool) -> Result<ParamPlan, params::Refusal> {
        let next = params::write(&self.settings, index, value)?;
        // `index` is known (`params::write` refused it otherwise). A
        // parameter writes only its own field: its value says whether
        // anything changed, its flag whether the change re-designs.
        let p = &params::PARAMS[index];
        if (p.get)(&next).to_bits() == (p.get)(&self.settings).to_bits() {
            return Ok(ParamPlan::Unchanged);
        }
        match (p.redesign, allow_redesign) {
            (false, _) => Ok(ParamPlan::Set(next)),
            (true, true) => Ok(ParamPlan::Redesign(next)),
            (true, false) => Err(params::Refusal::Armed),
        }
    }

    /// Applies a plan that needs no design ([`Loop::plan_param`]); a
    /// re-design's settings are returned, for the controller's side
    /// ([`apply_plan`]).
    pub fn apply_unless_design(&mut self, plan: ParamPlan) -> Option<params::Settings> {
        match plan {
            ParamPlan::Unchanged => None,
            ParamPlan::Set(next) => {
                self.settings = next;
                None
            }
            ParamPlan::Redesign(next) => Some(next),
        }
    }

    /// An `Imu` message's estimator half ([`Loop::on_imu`]) as a front end
    /// that speaks another protocol takes it: `None` (counted as
    /// unexpected) before the session opens, else the job for the
    /// controller.
    pub fn imu_job<C: CycleClock>(
        &mut self,
        seq: u32,
        t_us: u64,
        imu: &ImuSample,
        clock: &C,
        now_us: u64,
    ) -> Option<Job> {
        if !self.session {
            self.counters.unexpected = self.counters.unexpected.wrapping_add(1);
            return None;
        }
        self.counters.ok = self.counters.ok.wrapping_add(1);
        Some(Job::Step(self.on_imu(seq, t_us, imu, clock, now_us)))
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
        self.previews = [None; PREVIEW_SLOTS];
    }

    /// Hands the previews received since the controller's last step to
    /// `ctrl` (counted if it refuses one it takes).
    pub fn apply_previews(&mut self, ctrl: &mut AnyController<f32>) {
        for (k, slot) in self.previews.iter_mut().enumerate() {
            if let Some(sp) = slot.take() {
                if ctrl.set_preview(k, &sp).is_err() && self.takes_preview {
                    self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
                }
            }
        }
    }

    /// The frame decoder of the loop's link: bytes in, frames out for
    /// [`Loop::on_frame`].
    pub fn decoder(&mut self) -> &mut FrameDecoder<MAX_FRAME> {
        &mut self.decoder
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

    /// One decoded frame (or why it did not decode) as if it had arrived at
    /// `now_us`: counted, its immediate answers (handshake, heartbeat,
    /// parameter reads) to `out`, and what the controller must do returned.
    pub fn on_frame<O: Outbox, C: CycleClock>(
        &mut self,
        frame: Result<ToFc, FrameError>,
        out: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<Option<Job>, O::Error> {
        match frame {
            Ok(m) => self.on_message(m, out, clock, now_us),
            Err(e) => {
                match e {
                    FrameError::Oversized => self.counters.oversized = self.counters.oversized.wrapping_add(1),
                    FrameError::Cobs => self.counters.bad_cobs = self.counters.bad_cobs.wrapping_add(1),
                    FrameError::Crc => self.counters.bad_crc = self.counters.bad_crc.wrapping_add(1),
                    FrameError::Message | FrameError::BufferTooSmall => {
                        self.counters.bad_message = self.counters.bad_message.wrapping_add(1)
                    }
                }
                Ok(None)
            }
        }
    }

    /// One decoded message (see [`Loop::on_frame`]).
    pub fn on_message<O: Outbox, C: CycleClock>(
        &mut self,
        msg: ToFc,
        out: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<Option<Job>, O::Error> {
        self.counters.ok = self.counters.ok.wrapping_add(1);
        match msg {
            ToFc::Hello { version } => {
                let accepted = version == PROTOCOL_VERSION;
                if accepted {
                    self.open_session();
                }
                out.send(&FromFc::HelloAck {
                    version: PROTOCOL_VERSION,
                    accepted,
                })?;
            }
            _ if !self.session => self.counters.unexpected = self.counters.unexpected.wrapping_add(1),
            ToFc::Heartbeat { seq } => out.send(&FromFc::Heartbeat { seq })?,
            ToFc::Select {
                controller,
                feedforward,
            } => {
                // An id no controller has is a message this end cannot read
                // (as an unknown enum index was in protocol v2's decoder).
                match ControllerSpec::from_wire(controller, feedforward) {
                    Ok(spec) => return Ok(Some(Job::Select(spec))),
                    Err(_) => self.counters.bad_message = self.counters.bad_message.wrapping_add(1),
                }
            }
            ToFc::Setpoint(w) => match setpoint_from_wire(&w) {
                Some(sp) => self.sp = sp,
                None => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
            },
            ToFc::Preview { k, sp } => {
                // Held for the controller's next step ([`Loop::apply_previews`]).
                match (setpoint_from_wire(&sp), self.previews.get_mut(usize::from(k))) {
                    (Some(sp), Some(slot)) => *slot = Some(sp),
                    _ if self.takes_preview => {
                        self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1)
                    }
                    _ => {}
                }
            }
            ToFc::Sensor { seq, t_us, state } => {
                return Ok(Some(Job::Step(self.on_sensor(seq, t_us, &state, clock, now_us))))
            }
            ToFc::ParamRead { index } => out.send(&param_answer(&self.settings, index, None))?,
            ToFc::ParamSet { index, value } => {
                // Re-designs only before the session's first step: a
                // controller is not re-designed under a flying vehicle.
                return Ok(Some(Job::Param {
                    index,
                    value,
                    allow_redesign: self.last_seq.is_none(),
                }));
            }
            ToFc::Fix(w) => {
                // Queued in the navigator for the next `Imu` step; a full
                // queue drops and counts it (`Nav.fixes_rejected`).
                self.nav.push_fix(&fix_from_wire(&w));
            }
            ToFc::Imu { seq, t_us, gyro, accel } => {
                let imu = ImuSample {
                    gyro_frd_radps: Vector3::from(gyro),
                    accel_frd_mps2: Vector3::from(accel),
                };
                return Ok(Some(Job::Step(self.on_imu(seq, t_us, &imu, clock, now_us))));
            }
        }
        Ok(None)
    }

    /// The sequence and time checks of a control step (`Sensor` or `Imu`):
    /// `Some(now)` on the loop's clock if it is to be flown; `None` (counted)
    /// if its `seq` or, in lockstep, its time does not increase or jumps.
    fn accept_step(&mut self, seq: u32, t_us: u64, now_us: u64) -> Option<u64> {
        let lockstep = self.cfg.time_base == TimeBase::Lockstep;
        let absurd_time = lockstep
            && self
                .last_t_us
                .is_some_and(|last| t_us <= last || t_us - last > self.cfg.max_time_step_us);
        if self.last_seq.is_some_and(|last| seq <= last) || absurd_time {
            self.counters.out_of_order = self.counters.out_of_order.wrapping_add(1);
            return None;
        }
        self.last_seq = Some(seq);
        Some(if lockstep {
            self.last_t_us = Some(t_us);
            // The simulated time since the last valid step: past the
            // timeout it was a failsafe episode, even if this frame ends it.
            self.timeout_at(t_us);
            t_us
        } else {
            now_us
        })
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

    /// A full-state step (`Sensor`): checked, then the controller's step.
    fn on_sensor<C: CycleClock>(&mut self, seq: u32, t_us: u64, state: &[f32; 13], clock: &C, now_us: u64) -> Step {
        let mut step = Step {
            seq,
            t0: None,
            nav: false,
            control: None,
        };
        // Not flown, but answered (the held output, the counter in the
        // telemetry), so that a lockstep client waiting on this `seq` does
        // not block.
        let Some(now) = self.accept_step(seq, t_us, now_us) else {
            return step;
        };
        self.nav_failsafe = false;
        let est = StateEstimate::from_quat_state(&QuatState::from_column_slice(state));
        if !est.is_valid() || !self.plausible(&est, now) {
            self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
            return step;
        }
        self.last_pos = Some((est.pos_ned_m, now));
        let resume = self.take_resume(now);
        step.t0 = Some(clock.now());
        step.control = Some(self.control_job(now, est, self.sp, resume, false));
        step
    }

    /// Records the controller's result for `step` (`None`: it did not run)
    /// and returns the step's answers: the output now held, the telemetry,
    /// and the estimator's state for an `Imu` step.
    pub fn finish<C: CycleClock>(
        &mut self,
        step: &Step,
        result: Option<Result<ControlOutput<f32>, ControlError>>,
        clock: &C,
    ) -> Answers {
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
        let cycles = step.t0.map_or(0, |t0| clock.since(t0));
        let failsafe = self.failsafe || self.nav_failsafe;
        let mut answers = Answers::new();
        // Four pushes into a Vec of four: none fails.
        let _ = answers.push(FromFc::Actuator {
            seq: step.seq,
            u: [self.u[0], self.u[1], self.u[2], self.u[3]],
            failsafe,
        });
        let _ = answers.push(FromFc::Telemetry {
            seq: step.seq,
            cycles,
            qp_iterations: iterations,
            counters: self.counters,
            failsafe,
        });
        if step.nav {
            let (nav, bias) = self.nav_messages(step.seq);
            let _ = answers.push(nav);
            let _ = answers.push(bias);
        }
        answers
    }

    /// The `Nav` and `NavBias` messages of step `seq` (one covariance
    /// diagonal for both).
    fn nav_messages(&self, seq: u32) -> (FromFc, FromFc) {
        let (mode, est) = match (self.nav.mode(), self.nav.estimate()) {
            (NavMode::Navigating, Some(e)) => (1, Some(e)),
            (NavMode::Failsafe, Some(e)) => (2, Some(e)),
            _ => (0, None),
        };
        let s = self.nav.estimator().sigmas();
        let c = self.nav.counters();
        let nav = FromFc::Nav {
            seq,
            mode,
            pos: est.map_or([0.0; 3], |e| e.pos_ned_m.into()),
            vel: est.map_or([0.0; 3], |e| e.vel_ned_mps.into()),
            att: est.map_or([0.0; 4], |e| e.att.into()),
            sigma: [s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8]],
            imu_rejected: c.imu_rejected.wrapping_add(c.imu_clipped),
            fixes_rejected: c
                .pos_rejected
                .wrapping_add(c.vel_rejected)
                .wrapping_add(c.yaw_rejected)
                .wrapping_add(c.alt_rejected)
                .wrapping_add(c.fix_invalid)
                .wrapping_add(self.nav.fixes_dropped()),
            failsafe_entries: self.nav.failsafe_entries(),
        };
        let (bg, ba) = self.nav.estimator().biases();
        let bias = FromFc::NavBias {
            seq,
            gyro_bias: bg.into(),
            accel_bias: ba.into(),
            sigma: [s[9], s[10], s[11], s[12], s[13], s[14]],
        };
        (nav, bias)
    }
}

#[cfg(test)]
mod tests;
