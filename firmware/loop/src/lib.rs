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

pub mod nav;
pub mod params;
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
    /// [`FlightCore::service`] and [`FlightCore::check_timeout`]; the
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
    cfg: FcConfig,
    /// The parameters (vehicle, controller, failsafe; the motor settings
    /// are a front end's): `settings.vehicle` is what the controllers are
    /// designed for.
    settings: params::Settings,
    ctrl: AnyController<f32>,
    /// What `ctrl` was built from (rebuilt when a new selection fails).
    spec: ControllerSpec,
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
        let params = settings.vehicle;
        Self {
            cfg,
            settings,
            ctrl: AnyController::PdEuler(PdEuler::new(params, PdEulerGains::tuned(), ReferenceMode::Feedforward)),
            spec: FALLBACK_CONTROLLER,
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

    /// Designs the settings' controller (by default the boot controller,
    /// [`BOOT_CONTROLLER`]) in place for their vehicle. On error (settings
    /// [`params::Settings::check`] refuses, or a failed design) the loop
    /// keeps flying the fallback PD.
    pub fn start(&mut self) -> Result<(), ControlError> {
        self.settings.check().map_err(|_| ControlError::InvalidParameter)?;
        // Unstarted, the previous controller is the fallback PD.
        self.install(self.settings.controller)
    }

    /// For a protocol front end (MAVLink, CRTP): checks the settings,
    /// designs their controller in place ([`FlightCore::start`]), opens the
    /// session (set-points may come before samples) and returns the mixer
    /// the settings give for the front end's motors.
    pub fn start_front_end(&mut self) -> Result<fc_core::model::airframe::Mixer<f32>, params::Refusal> {
        self.settings.check()?;
        self.start().map_err(params::Refusal::Design)?;
        self.open_session();
        self.settings.mixer()
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
        if !self.session {
            self.counters.unexpected = self.counters.unexpected.wrapping_add(1);
            return Ok(());
        }
        self.counters.ok = self.counters.ok.wrapping_add(1);
        self.on_imu(seq, t_us, imu, out, clock, now_us)
    }

    /// Queues a position fix for the next `Imu` step, as a `Fix` message does.
    pub fn push_fix(&mut self, fix: &Fix) {
        self.nav.push_fix(fix);
    }

    /// The parameters in force.
    pub fn settings(&self) -> &params::Settings {
        &self.settings
    }

    /// Sets parameter `index` ([`params::PARAMS`]) to `value`: the whole
    /// settings checked; a change of the vehicle, the controller or its
    /// gains and weights re-designs it, which only `allow_redesign` permits
    /// (a front end says whether the vehicle is disarmed). A refusal leaves
    /// everything as it was.
    pub fn apply_param(&mut self, index: usize, value: f32, allow_redesign: bool) -> Result<(), params::Refusal> {
        use params::Refusal;
        let next = params::write(&self.settings, index, value)?;
        // `index` is known (`params::write` refused it otherwise). A
        // parameter writes only its own field: its value says whether
        // anything changed, its flag whether the change re-designs.
        let p = &params::PARAMS[index];
        if (p.get)(&next).to_bits() == (p.get)(&self.settings).to_bits() {
            return Ok(());
        }
        if p.redesign && !allow_redesign {
            return Err(Refusal::Armed);
        }
        if p.redesign {
            let old = self.settings;
            self.settings.vehicle = next.vehicle;
            self.settings.tuning = next.tuning;
            let selected = next.controller != old.controller;
            if let Err(e) = self.install(next.controller) {
                // Back to the old settings, and their controller (it was
                // designed from them before).
                self.settings = old;
                let _ = self.install(old.controller);
                return Err(Refusal::Design(e));
            }
            if selected {
                self.selections = self.selections.wrapping_add(1);
            }
        }
        self.settings = next;
        Ok(())
    }

    /// Answers a parameter request of our protocol: parameter `index`'s
    /// value, and why a write was refused (0: it was not).
    fn send_param<O: Outbox>(&self, index: u16, refusal: Option<params::Refusal>, out: &mut O) -> Result<(), O::Error> {
        out.send(&param_answer(&self.settings, index, refusal))
    }

    /// Designs `spec` in place of the running controller (as a `Select`
    /// does); on failure the running one keeps flying and the error is
    /// returned. Not in flight: a design takes milliseconds to tens of them.
    pub fn try_select(&mut self, spec: ControllerSpec) -> Result<(), ControlError> {
        self.install(spec)?;
        self.selections = self.selections.wrapping_add(1);
        Ok(())
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
        for _ in 0..self.cfg.max_reads_per_service {
            let n = link.read(&mut buf)?;
            if n == 0 {
                break;
            }
            for &b in &buf[..n.min(buf.len())] {
                if let Some(frame) = self.decoder.push::<ToFc>(b) {
                    self.handle(frame, &mut Framed(link), clock, now_us)?;
                }
            }
        }
        self.check_timeout(now_us);
        Ok(())
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
        schedule::period_us(self.ctrl.period_s().unwrap_or(self.cfg.control_period_s))
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

    /// Designs `spec` in place of the running controller. If the design
    /// fails, the previous controller is designed again (it was designed
    /// from the same parameters before, so it succeeds; should it not, the
    /// tuned Euler PD, which cannot fail, flies) and the failure is counted.
    fn select(&mut self, spec: ControllerSpec) {
        match self.install(spec) {
            Ok(()) => self.selections = self.selections.wrapping_add(1),
            Err(_) => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
        }
    }

    /// Designs `spec` in place of the running controller; on failure the
    /// running one is designed again (the slot no longer holds it), or the
    /// fallback PD if even that fails, and the error is returned.
    fn install(&mut self, spec: ControllerSpec) -> Result<(), ControlError> {
        let ts = self.cfg.control_period_s;
        let result = spec.build_in(&mut self.ctrl, self.settings.vehicle, ts, None, &self.settings.tuning);
        if result.is_ok() {
            self.spec = spec;
            self.settings.controller = spec;
        } else if self
            .spec
            .build_in(&mut self.ctrl, self.settings.vehicle, ts, None, &self.settings.tuning)
            .is_err()
        {
            self.spec = FALLBACK_CONTROLLER;
            // PD designs cannot fail: nothing to check.
            let _ =
                FALLBACK_CONTROLLER.build_in(&mut self.ctrl, self.settings.vehicle, ts, None, &self.settings.tuning);
        }
        result
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

    /// The controller's step at `now_us`, told the measured interval since
    /// its last one (a 2 ms simulator under a 1 ms controller, a late
    /// sample), or resumed when that interval is a gap.
    fn control_step(
        &mut self,
        est: &StateEstimate<f32>,
        sp: &Setpoint<f32>,
        now_us: u64,
    ) -> Result<ControlOutput<f32>, ControlError> {
        if let Some(t) = self.last_control_us {
            let period_s = self.period_us() as f64 * 1e-6;
            fc_core::control::tell_interval(&mut self.ctrl, now_us.saturating_sub(t), period_s);
        }
        self.last_control_us = Some(now_us);
        self.ctrl.update(est, sp)
    }

    fn handle<O: Outbox, C: CycleClock>(
        &mut self,
        frame: Result<ToFc, FrameError>,
        link: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<(), O::Error> {
        match frame {
            Ok(m) => self.handle_message(m, link, clock, now_us),
            Err(e) => {
                match e {
                    FrameError::Oversized => self.counters.oversized = self.counters.oversized.wrapping_add(1),
                    FrameError::Cobs => self.counters.bad_cobs = self.counters.bad_cobs.wrapping_add(1),
                    FrameError::Crc => self.counters.bad_crc = self.counters.bad_crc.wrapping_add(1),
                    FrameError::Message | FrameError::BufferTooSmall => {
                        self.counters.bad_message = self.counters.bad_message.wrapping_add(1)
                    }
                }
                Ok(())
            }
        }
    }

    /// Handles one decoded message as if it had arrived on the link at
    /// `now_us`, its answers to `out`: the entry of front ends that speak
    /// another protocol (MAVLink) and translate into this one.
    pub fn handle_message<O: Outbox, C: CycleClock>(
        &mut self,
        msg: ToFc,
        link: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<(), O::Error> {
        self.counters.ok = self.counters.ok.wrapping_add(1);
        match msg {
            ToFc::Hello { version } => {
                let accepted = version == PROTOCOL_VERSION;
                if accepted {
                    self.open_session();
                }
                link.send(&FromFc::HelloAck {
                    version: PROTOCOL_VERSION,
                    accepted,
                })
            }
            _ if !self.session => {
                self.counters.unexpected = self.counters.unexpected.wrapping_add(1);
                Ok(())
            }
            ToFc::Heartbeat { seq } => link.send(&FromFc::Heartbeat { seq }),
            ToFc::Select {
                controller,
                feedforward,
            } => {
                // An id no controller has is a message this end cannot read
                // (as an unknown enum index was in protocol v2's decoder).
                match ControllerSpec::from_wire(controller, feedforward) {
                    Ok(spec) => self.select(spec),
                    Err(_) => self.counters.bad_message = self.counters.bad_message.wrapping_add(1),
                }
                Ok(())
            }
            ToFc::Setpoint(w) => {
                match setpoint_from_wire(&w) {
                    Some(sp) => self.sp = sp,
                    None => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
                }
                Ok(())
            }
            ToFc::Preview { k, sp } => {
                let ok = setpoint_from_wire(&sp).is_some_and(|s| self.ctrl.set_preview(k as usize, &s).is_ok());
                if !ok && self.ctrl.preview_request().is_some() {
                    self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
                }
                Ok(())
            }
            ToFc::Sensor { seq, t_us, state } => self.on_sensor(seq, t_us, &state, link, clock, now_us),
            ToFc::ParamRead { index } => self.send_param(index, None, link),
            ToFc::ParamSet { index, value } => {
                // Re-designs only before the session's first step: a
                // controller is not re-designed under a flying vehicle.
                let r = self.apply_param(usize::from(index), value, self.last_seq.is_none());
                if r.is_err() {
                    self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
                }
                self.send_param(index, r.err(), link)
            }
            ToFc::Fix(w) => {
                // Queued in the navigator for the next `Imu` step; a full
                // queue drops and counts it (`Nav.fixes_rejected`).
                self.nav.push_fix(&fix_from_wire(&w));
                Ok(())
            }
            ToFc::Imu { seq, t_us, gyro, accel } => {
                let imu = ImuSample {
                    gyro_frd_radps: Vector3::from(gyro),
                    accel_frd_mps2: Vector3::from(accel),
                };
                self.on_imu(seq, t_us, &imu, link, clock, now_us)
            }
        }
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

    /// One IMU step: the estimator integrates the sample (with the fixes
    /// received since the last step); when the controller is due it flies
    /// the estimate — the mission's setpoint, or the estimator's failsafe
    /// hold-and-descend; while aligning, hover thrust and no torque. Every
    /// step is answered (the output held since the controller last ran)
    /// with a `Nav` message added.
    fn on_imu<O: Outbox, C: CycleClock>(
        &mut self,
        seq: u32,
        t_us: u64,
        imu: &ImuSample,
        link: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<(), O::Error> {
        let Some(now) = self.accept_step(seq, t_us, now_us) else {
            return self.reply(seq, 0, 0, link);
        };
        let lockstep = self.cfg.time_base == TimeBase::Lockstep;
        let t0 = clock.now();
        let stepped = self.nav.step(now, imu, &[]);
        // Asked at every step, so that the grid follows the steps' times.
        let control = self.schedule.due(now, self.period_us());
        let mut iterations = 0u16;
        match (stepped, self.nav.estimate()) {
            (Ok(mode @ (NavMode::Navigating | NavMode::Failsafe)), Some(est)) => {
                self.nav_failsafe = mode == NavMode::Failsafe;
                if control {
                    if self.failsafe || (lockstep && self.gap_since_last_step(now)) {
                        self.ctrl.resume();
                        self.failsafe = false;
                    }
                    let sp = self.nav.setpoint(now, &self.sp);
                    if self.nav_failsafe {
                        Navigator::preview_along(&mut self.ctrl, &sp);
                    }
                    match self.control_step(&est, &sp, now) {
                        Ok(o) => {
                            self.u = o.u;
                            iterations = o.status.iterations;
                            self.last_valid_us = Some(now);
                        }
                        Err(_) => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
                    }
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
        let cycles = clock.since(t0);
        self.reply(seq, cycles, iterations, link)?;
        self.send_nav(seq, link)
    }

    /// Sends the `Nav` and `NavBias` messages of step `seq` (one covariance
    /// diagonal for both, one message on the stack at a time).
    fn send_nav<O: Outbox>(&self, seq: u32, link: &mut O) -> Result<(), O::Error> {
        let (mode, est) = match (self.nav.mode(), self.nav.estimate()) {
            (NavMode::Navigating, Some(e)) => (1, Some(e)),
            (NavMode::Failsafe, Some(e)) => (2, Some(e)),
            _ => (0, None),
        };
        let s = self.nav.estimator().sigmas();
        let c = self.nav.counters();
        link.send(&FromFc::Nav {
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
        })?;
        let (bg, ba) = self.nav.estimator().biases();
        link.send(&FromFc::NavBias {
            seq,
            gyro_bias: bg.into(),
            accel_bias: ba.into(),
            sigma: [s[9], s[10], s[11], s[12], s[13], s[14]],
        })
    }

    #[allow(clippy::too_many_arguments)]
    fn on_sensor<O: Outbox, C: CycleClock>(
        &mut self,
        seq: u32,
        t_us: u64,
        state: &[f32; 13],
        link: &mut O,
        clock: &C,
        now_us: u64,
    ) -> Result<(), O::Error> {
        let lockstep = self.cfg.time_base == TimeBase::Lockstep;
        let Some(now) = self.accept_step(seq, t_us, now_us) else {
            // Not flown, but answered (the held output, the counter in the
            // telemetry), so that a lockstep client waiting on this `seq`
            // does not block.
            return self.reply(seq, 0, 0, link);
        };
        self.nav_failsafe = false;
        let est = StateEstimate::from_quat_state(&QuatState::from_column_slice(state));
        let mut cycles = 0u32;
        let mut iterations = 0u16;
        if !est.is_valid() || !self.plausible(&est, now) {
            self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1);
        } else {
            self.last_pos = Some((est.pos_ned_m, now));
            if self.failsafe || (lockstep && self.gap_since_last_step(now)) {
                // Valid data again after a gap: the controller keeps its
                // estimates and forgets only the step before (see `Controller::resume`).
                self.ctrl.resume();
                self.failsafe = false;
            }
            let t0 = clock.now();
            let sp = self.sp;
            let out = self.control_step(&est, &sp, now);
            cycles = clock.since(t0);
            match out {
                Ok(o) => {
                    self.u = o.u;
                    iterations = o.status.iterations;
                    self.last_valid_us = Some(now);
                }
                Err(_) => self.counters.invalid_values = self.counters.invalid_values.wrapping_add(1),
            }
        }
        self.reply(seq, cycles, iterations, link)
    }

    /// Answers sensor frame `seq`: the output now held, then the telemetry.
    fn reply<O: Outbox>(&self, seq: u32, cycles: u32, iterations: u16, link: &mut O) -> Result<(), O::Error> {
        let u = [self.u[0], self.u[1], self.u[2], self.u[3]];
        link.send(&FromFc::Actuator {
            seq,
            u,
            failsafe: self.failsafe || self.nav_failsafe,
        })?;
        link.send(&FromFc::Telemetry {
            seq,
            cycles,
            qp_iterations: iterations,
            counters: self.counters,
            failsafe: self.failsafe || self.nav_failsafe,
        })
    }
}

#[cfg(test)]
mod tests;
