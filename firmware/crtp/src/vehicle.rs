//! The flight controller behind CRTP: [`CrtpVehicle`] answers cflib and
//! cfclient as a Crazyflie (firmware protocol version 12) does and flies
//! the flight loop ([`fc_loop::Loop`] and its controller) on its own
//! sensors.
//!
//! It is two parts, as the flight loop is: [`CrtpCore`], everything but the
//! controller (the packets, the modes, the supervisor, the loop), and the
//! controller. In-process ([`CrtpVehicle`]) they step together. An image
//! that runs the IMU, the controller and the link at three interrupt
//! priorities keeps them apart: the IMU task takes each sample's estimator
//! half ([`CrtpCore::imu_begin`]), the controller's task flies it
//! ([`fly_step`]) and runs the controller work a packet asked for
//! ([`CrtpCore::take_work`], [`run_work`]) — a take-off's reset, a
//! parameter write that re-designs (answered once it is done) — and the
//! link's task handles packets under short locks of the [`CrtpCore`].
//!
//! Services (port: what):
//! - link (15): echo (channel 0), "Bitcraze Crazyflie" (source, 1), sink
//!   (2); a null packet is answered with a null packet.
//! - platform (13): protocol version [`crate::PROTOCOL_VERSION`], firmware
//!   version, device type name; the legacy arming and recovery commands.
//! - log (5): TOC v2 of [`LOG_VARS`], blocks ([`crate::log`]).
//! - param (2): TOC v2 of [`fc_loop::params::PARAMS`] (group = the name's
//!   prefix in lower case: `MPC_W_POS` is `mpc.W_POS`) and of
//!   [`EXTRA_PARAMS`] (the Crazyflie names cflib's helpers and examples
//!   use); read, write (answered with the value in force), set by name,
//!   default values, extended types; persistent storage refused.
//! - mem (4): no memories. console (0): what a user should see.
//! - high-level commander (8): takeoff, land, go_to (absolute, relative,
//!   linear), stop — [`crate::planner`] segments flown as position,
//!   velocity and acceleration references.
//! - generic set-points (7): stop, position, velocity in the world frame,
//!   hover; "notify set-point stop" hands back to the high-level commander.
//!   The Crazyflie's watchdog: a set-point older than
//!   [`SETPOINT_LEVEL_MS`] is held level where it is, older than
//!   [`SETPOINT_STOP_MS`] the motors stop.
//! - localization (6): external position (channel 0) and pose (`EXT_POSE`)
//!   as the estimator's position and heading fix; emergency stop.
//! - supervisor (9): arming, recovery, emergency stop, the state bits.
//! - legacy commander (3): thrust 0 stops the motors (cflib sends it on
//!   disconnecting); attitude set-points are refused.
//!
//! Armed without a set-point, the motors are off, as on a Crazyflie. The
//! core's own checks (finite, plausible set-points; the estimator's
//! failsafe) apply as on every protocol.

use crate::log::{self, LogBlocks};
use crate::persist::PersistRequest;
use crate::planner::{Reference, Segment};
use crate::supervisor::{ImuCounters, ImuGuard, SensorDown, BATTERY_FLOOR_V, FAILSAFE_DESCENT_MPS, IMU_TIMEOUT_US};
use crate::toc::{self, Name};
use crate::{f32_at, frames, u16_at, CrtpCounters, CrtpError, Packet, Port};
use core::borrow::BorrowMut;
use core::convert::Infallible;
use core::fmt::Write as _;
use fc_core::control::Setpoint;
use fc_core::control::{AnyController, Controller};
use fc_core::estimate::{Fix, ImuSample};
use fc_core::model::airframe::Mixer;
use fc_loop::baro::Barometer;
use fc_loop::nav::NavMode;
use fc_loop::params::{ParamType, Refusal, Settings, PARAMS};
use fc_loop::{run_job, FcConfig, Job, Loop, Mutex, Outbox, ParamPlan};
use fc_proto::FromFc;
use hal_shim::CycleClock;
use nalgebra::{Vector3, Vector4};

/// A generic set-point older than this is held level where it is, ms.
pub const SETPOINT_LEVEL_MS: u64 = 500;
/// A generic set-point older than this stops the motors, ms.
pub const SETPOINT_STOP_MS: u64 = 2000;
/// Tilt beyond which an armed vehicle is tumbled: motors off, rad (60°).
pub const TUMBLE_TILT_RAD: f32 = core::f32::consts::FRAC_PI_3;
/// cos([`TUMBLE_TILT_RAD`]): the supervisor compares the body z axis' down
/// component with it every step, so it is not computed there (libm's
/// `cosf` works in f64, which the Cortex-M4 has no unit for: ≈ 1 000
/// instructions a step).
pub const COS_TUMBLE_TILT: f32 = 0.5;
/// A landing has landed within this of its goal height, m.
pub const LANDED_M: f32 = 0.05;
/// 1σ of an external position (the Crazyflie's `locSrv.extPosStdDev`), m.
pub const EXTPOS_SIGMA_M: f32 = 0.01;
/// 1σ of an external pose's heading (`locSrv.extQuatStdDev`), rad.
pub const EXTPOSE_SIGMA_RAD: f32 = 0.0045;
/// While the estimator aligns on external positions alone, the heading it
/// boots with is the Crazyflie's convention, facing +x (0), with this 1σ, rad.
pub const BOOT_HEADING_SIGMA_RAD: f32 = 0.05;
/// Device type name (platform port).
pub const DEVICE_TYPE_NAME: &str = "Crazyflie 2.1 (fc-core)";
/// Firmware version (platform port).
pub const FIRMWARE_VERSION: &str = concat!("fc-core ", env!("CARGO_PKG_VERSION"));
/// Console packets waiting to be sent, at most.
pub const CONSOLE_QUEUE: usize = 8;
/// Sampled log blocks waiting for the link, at most (one per block: a
/// full queue drops the oldest, as a radio that cannot keep up would).
pub const LOG_QUEUE: usize = crate::log::MAX_BLOCKS;

/// Where [`CrtpVehicle`]'s packets go (a UDP socket on the host, syslink
/// on a board).
pub trait CrtpSink {
    /// What sending can fail with.
    type Error;
    /// Sends `p`.
    fn send(&mut self, p: &Packet) -> Result<(), Self::Error>;
    /// Where persistent parameters are kept, if anywhere (cflib's
    /// `param.persistent_store`, answered by [`PersistRequest::answer`]);
    /// `None`: nothing persists, and a request to store is answered with
    /// an error.
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        None
    }
}

/// One log variable: its name, its log type, and how it is read.
#[derive(Debug, Clone, Copy)]
pub struct LogVar {
    /// Group.
    pub group: &'static str,
    /// Name.
    pub name: &'static str,
    /// Log type ([`crate::log::types`]).
    pub kind: u8,
}

macro_rules! vars {
    ($($group:literal . $name:literal : $kind:ident),+ $(,)?) => {
        /// The log TOC, in id order. Positions and velocities are in the
        /// Crazyflie's world frame (x forward, y left, z up; m, m/s),
        /// angles in degrees (roll right-side-down, pitch nose-up and yaw
        /// counter-clockwise positive), `kalman.varP*` the estimator's
        /// position variances (m²), `pm.vbat` volts, `motor.m*` the
        /// commands as fractions of 65 535.
        pub const LOG_VARS: &[LogVar] = &[$(LogVar { group: $group, name: $name, kind: log::types::$kind }),+];
    };
}

vars! {
    "stateEstimate"."x": FLOAT, "stateEstimate"."y": FLOAT, "stateEstimate"."z": FLOAT,
    "stateEstimate"."vx": FLOAT, "stateEstimate"."vy": FLOAT, "stateEstimate"."vz": FLOAT,
    "stateEstimate"."roll": FLOAT, "stateEstimate"."pitch": FLOAT, "stateEstimate"."yaw": FLOAT,
    "stabilizer"."roll": FLOAT, "stabilizer"."pitch": FLOAT, "stabilizer"."yaw": FLOAT,
    "stabilizer"."thrust": FLOAT,
    "kalman"."varPX": FLOAT, "kalman"."varPY": FLOAT, "kalman"."varPZ": FLOAT,
    "pm"."vbat": FLOAT, "pm"."state": I8,
    "motor"."m1": U16, "motor"."m2": U16, "motor"."m3": U16, "motor"."m4": U16,
    "sys"."canfly": U8, "sys"."armed": U8, "supervisor"."info": U16,
    "ctrltarget"."x": FLOAT, "ctrltarget"."y": FLOAT, "ctrltarget"."z": FLOAT,
}

/// Param type bytes (cflib's `ParamTocElement.types`).
pub mod param_types {
    /// `uint8_t`.
    pub const U8: u8 = 0x08;
    /// `uint16_t`.
    pub const U16: u8 = 0x09;
    /// `float`.
    pub const FLOAT: u8 = 0x06;
    /// Flag: read-only (`PARAM_RONLY`); cflib refuses to write it.
    pub const RONLY: u8 = 0x40;
    /// Flag: extended type information (`PARAM_EXTENDED`); cflib asks for
    /// it, and ours says "persistent".
    pub const EXTENDED: u8 = 0x10;
    /// The type's bits (size, integer or float, signedness) under the flags.
    pub const TYPE: u8 = 0x0F;
}

/// A parameter under a Crazyflie name, beside [`PARAMS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Extra {
    /// `kalman.resetEstimation`: 1 restarts the estimator (on the ground).
    ResetEstimation,
    /// `stabilizer.controller`: our controller id (`CTL_ID`).
    Controller,
    /// `stabilizer.estimator`: 2, the Kalman filter (the only one here).
    Estimator,
    /// `commander.enHighLevel`: 1, the high-level commander is always on.
    EnHighLevel,
    /// `pid_attitude.*`: the PD controller's attitude gain [`PARAMS`] index.
    Alias(usize),
    /// `deck.bc*`: read-only, 0: no expansion deck is attached. cfclient's
    /// flight tab reads them to offer height hold and command-based flight.
    Deck,
}

/// The index in [`PARAMS`] of the parameter named `id` (a compile-time
/// lookup: a name that is not there does not build).
const fn param_index(id: &str) -> usize {
    let mut i = 0;
    while i < PARAMS.len() {
        let (a, b) = (PARAMS[i].id.as_bytes(), id.as_bytes());
        if a.len() == b.len() {
            let mut k = 0;
            while k < a.len() && a[k] == b[k] {
                k += 1;
            }
            if k == a.len() {
                return i;
            }
        }
        i += 1;
    }
    panic!("no such parameter")
}

/// `CTL_ID`'s index.
const CTL_ID: usize = param_index("CTL_ID");

/// The Crazyflie-named parameters after [`PARAMS`] in the param TOC.
pub const EXTRA_PARAMS: [(&str, &str, u8, Extra); 18] = [
    ("kalman", "resetEstimation", param_types::U8, Extra::ResetEstimation),
    ("stabilizer", "controller", param_types::U8, Extra::Controller),
    ("stabilizer", "estimator", param_types::U8, Extra::Estimator),
    ("commander", "enHighLevel", param_types::U8, Extra::EnHighLevel),
    (
        "pid_attitude",
        "roll_kp",
        param_types::FLOAT,
        Extra::Alias(param_index("PD_ROLL_P")),
    ),
    (
        "pid_attitude",
        "roll_kd",
        param_types::FLOAT,
        Extra::Alias(param_index("PD_ROLL_D")),
    ),
    (
        "pid_attitude",
        "pitch_kp",
        param_types::FLOAT,
        Extra::Alias(param_index("PD_PITCH_P")),
    ),
    (
        "pid_attitude",
        "pitch_kd",
        param_types::FLOAT,
        Extra::Alias(param_index("PD_PITCH_D")),
    ),
    (
        "pid_attitude",
        "yaw_kp",
        param_types::FLOAT,
        Extra::Alias(param_index("PD_YAW_P")),
    ),
    (
        "pid_attitude",
        "yaw_kd",
        param_types::FLOAT,
        Extra::Alias(param_index("PD_YAW_D")),
    ),
    ("deck", "bcFlow", DECK, Extra::Deck),
    ("deck", "bcFlow2", DECK, Extra::Deck),
    ("deck", "bcZRanger", DECK, Extra::Deck),
    ("deck", "bcZRanger2", DECK, Extra::Deck),
    ("deck", "bcLighthouse4", DECK, Extra::Deck),
    ("deck", "bcLoco", DECK, Extra::Deck),
    ("deck", "bcDWM1000", DECK, Extra::Deck),
    ("deck", "bcLedRing", DECK, Extra::Deck),
];

/// A deck's attached flag: `PARAM_UINT8 | PARAM_RONLY`, as the firmware's deck drivers declare it.
const DECK: u8 = param_types::U8 | param_types::RONLY;

/// Entries in the param TOC.
pub const PARAM_COUNT: usize = PARAMS.len() + EXTRA_PARAMS.len();

/// Group and name of param `id`, its type byte, and what it is.
pub fn param_entry(id: usize) -> Option<(Name<'static>, u8, Option<Extra>)> {
    if let Some(p) = PARAMS.get(id) {
        let (group, name) = p.id.split_once('_').unwrap_or(("fc", p.id));
        return Some((
            Name {
                group,
                name,
                lower_group: true,
            },
            // Its true type; every flight parameter persists, as the
            // Crazyflie's tuning does.
            toc_type(p.ty) | param_types::EXTENDED,
            None,
        ));
    }
    let &(group, name, t, extra) = EXTRA_PARAMS.get(id - PARAMS.len())?;
    Some((
        Name {
            group,
            name,
            lower_group: false,
        },
        t,
        Some(extra),
    ))
}

/// The param TOC's type byte of a parameter of type `ty`.
const fn toc_type(ty: ParamType) -> u8 {
    match ty {
        ParamType::F32 => param_types::FLOAT,
        ParamType::U8 => param_types::U8,
        ParamType::U16 => param_types::U16,
    }
}

/// How the vehicle flies now.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    /// Motors off (armed or not): no set-point, stopped, landed.
    Idle,
    /// The high-level commander's segment (`landing`: stop at its end).
    High { seg: Segment, landing: bool },
    /// A generic set-point received at `last_us`; a velocity set-point
    /// moves `sp`'s position at its velocity. `handover_us`: when control
    /// returns to the high-level commander (notify set-point stop).
    Generic {
        sp: Setpoint<f32>,
        last_us: u64,
        handover_us: Option<u64>,
    },
}

/// The flight loop's answers to one `Imu` step, kept.
#[derive(Default)]
struct Answer {
    u: Option<[f32; 4]>,
}

impl Outbox for Answer {
    type Error = Infallible;
    fn send(&mut self, msg: &FromFc) -> Result<(), Infallible> {
        if let FromFc::Actuator { u, .. } = msg {
            self.u = Some(*u);
        }
        Ok(())
    }
}

/// Console text, cut into packets of up to 30 bytes as the Crazyflie's
/// console sends it (cflib joins them): each full packet is queued, the
/// oldest dropped when the queue is full.
struct Line<'a> {
    p: Packet,
    queue: &'a mut heapless::Deque<Packet, CONSOLE_QUEUE>,
}

impl Line<'_> {
    fn push(&mut self) {
        if self.p.payload().is_empty() {
            return;
        }
        if self.queue.is_full() {
            self.queue.pop_front();
        }
        let _ = self.queue.push_back(self.p);
        if let Ok(p) = Packet::new(Port::Console, 0, &[]) {
            self.p = p;
        }
    }
}

impl core::fmt::Write for Line<'_> {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for b in s.bytes() {
            if self.p.extend(&[b]).is_err() {
                self.push();
                let _ = self.p.extend(&[b]);
            }
        }
        Ok(())
    }
}

/// Controller work a packet (or the simulator) asked for, run on the
/// controller's side ([`run_work`]).
#[derive(Debug, Clone, Copy)]
#[allow(
    clippy::large_enum_variant,
    reason = "no allocation: the work is held in place, one at a time"
)]
pub enum ControllerWork {
    /// Forget the controller's state before flying (a take-off from idle:
    /// nothing wound up on the ground): `Controller::reset`, which returns
    /// it to what its design gave, without designing again.
    Reset,
    /// A parameter write that re-designs: these settings, then the answer.
    Param {
        /// The settings with the value written.
        next: Settings,
        /// Who is answered.
        reply: Reply,
    },
}

impl ControllerWork {
    /// It designs a controller (tens of milliseconds on the chip without a
    /// controller step); a reset is a few stores.
    pub fn designs(&self) -> bool {
        matches!(self, ControllerWork::Param { .. })
    }
}

/// Who a re-designing parameter write answers once its design is done.
#[derive(Debug, Clone, Copy)]
pub enum Reply {
    /// A CRTP client: the request (a write by id, or by name).
    Crtp(Packet),
    /// The board's simulator: our protocol's `ParamSet` of this index.
    Sim(u16),
    /// The caller ([`CrtpVehicle::write_param`]).
    Caller,
}

/// What a parameter write did.
enum Written {
    /// Done: answer now.
    Now,
    /// A re-design was queued: answered when it is done.
    Later,
}

/// An IMU step's estimator half ([`CrtpCore::imu_begin`]), for the
/// controller's side ([`fly_step`]).
#[derive(Debug, Clone, Copy)]
pub struct ImuStep {
    /// The loop's job for the controller (`None`: no session, not flown).
    pub job: Option<Job>,
    /// A set-point is flown (a mode other than idle gave one).
    pub setpoint: bool,
}

/// The [`Loop`] inside a locked [`CrtpCore`], as [`run_job`] locks it.
struct LoopOf<'a, M>(&'a mut M);

impl<M: Mutex> Mutex for LoopOf<'_, M>
where
    M::T: BorrowMut<CrtpCore>,
{
    type T = Loop;
    fn lock<R>(&mut self, f: impl FnOnce(&mut Loop) -> R) -> R {
        self.0.lock(|v| f(&mut v.borrow_mut().core))
    }
}

/// Flies `step` on the controller `ctrl` (the controller's task), the
/// vehicle `v` locked only to take the step's inputs and record its
/// result; returns the inputs to apply `[U1 N, U2 N, U3 N, U4 N·m]`.
pub fn fly_step<M: Mutex, C: CycleClock>(
    v: &mut M,
    ctrl: &mut AnyController<f32>,
    step: ImuStep,
    clock: &C,
) -> Vector4<f32>
where
    M::T: BorrowMut<CrtpCore>,
{
    let mut answer = Answer::default();
    if let Some(job) = step.job {
        let _ = run_job(&mut LoopOf(v), ctrl, job, &mut answer, clock);
    }
    v.lock(|v| v.borrow_mut().imu_end(&step, answer.u))
}

/// Answers `step` without a controller: the controller's task's step while
/// its controller is lent to a re-design ([`ControllerWork::designs`]),
/// which runs only disarmed with no mode flown (a take-off is refused while
/// one is under way). The loop records the step as one the controller did
/// not fly; the motors stay off. Returns the inputs applied (zero).
pub fn pass_step<M: Mutex, C: CycleClock>(v: &mut M, step: ImuStep, clock: &C) -> Vector4<f32>
where
    M::T: BorrowMut<CrtpCore>,
{
    if let Some(Job::Step(s)) = step.job {
        let _ = LoopOf(v).lock(|l| l.finish(&s, None, clock));
    }
    v.lock(|v| v.borrow_mut().imu_end(&step, None))
}

/// Runs `work` ([`CrtpCore::take_work`]) on the controller `ctrl`, the
/// design with the vehicle `v` unlocked; returns its result and, for the
/// simulator's write, its answer ([`CrtpCore::work_done`]).
pub fn run_work<M: Mutex>(
    v: &mut M,
    ctrl: &mut AnyController<f32>,
    work: ControllerWork,
) -> (Result<(), Refusal>, Option<FromFc>)
where
    M::T: BorrowMut<CrtpCore>,
{
    let r = match work {
        ControllerWork::Reset => {
            ctrl.reset();
            Ok(())
        }
        ControllerWork::Param { next, .. } => fc_loop::apply_plan(&mut LoopOf(v), ctrl, ParamPlan::Redesign(next)),
    };
    let answer = v.lock(|v| v.borrow_mut().work_done(&work, r));
    (r, answer)
}

/// The flight controller behind CRTP in one piece (see the module's
/// documentation): a [`CrtpCore`] (reached through `Deref`) and its
/// controller, whose work runs at once.
pub struct CrtpVehicle {
    core: CrtpCore,
    ctrl: AnyController<f32>,
}

impl core::ops::Deref for CrtpVehicle {
    type Target = CrtpCore;
    fn deref(&self) -> &CrtpCore {
        &self.core
    }
}

impl core::ops::DerefMut for CrtpVehicle {
    fn deref_mut(&mut self) -> &mut CrtpCore {
        &mut self.core
    }
}

/// The vehicle reached directly: the controller work a locked moment
/// asked for runs before the lock ends (syslink's packets, in-process).
impl Mutex for CrtpVehicle {
    type T = CrtpCore;
    fn lock<R>(&mut self, f: impl FnOnce(&mut CrtpCore) -> R) -> R {
        let r = f(&mut self.core);
        self.run_pending();
        r
    }
}

impl CrtpVehicle {
    /// A vehicle with `settings` (checked; the controller designed),
    /// disarmed, its estimator waiting for samples.
    pub fn new(settings: Settings) -> Result<Self, Refusal> {
        let mut v = Self::unstarted(settings);
        v.start()?;
        Ok(v)
    }

    /// The vehicle with nothing designed yet (motors off until
    /// [`CrtpVehicle::start`] succeeds), for a static home on the image.
    pub fn unstarted(settings: Settings) -> Self {
        Self {
            core: CrtpCore::unstarted(settings),
            ctrl: fc_loop::fallback_controller(settings.vehicle),
        }
    }

    /// The values `MISC_GET_DEFAULT_VALUE` and `persistent_get_state`
    /// report as defaults: the built-in ones, where the vehicle booted with
    /// stored values (by default, the settings it was made with).
    pub fn set_defaults(&mut self, defaults: Settings) {
        self.core.defaults = defaults;
    }

    /// Checks the settings and designs the controller in place.
    pub fn start(&mut self) -> Result<(), Refusal> {
        self.core.mixer = Some(fc_loop::start_front_end(&mut self.core.core, &mut self.ctrl)?);
        Ok(())
    }

    /// The shared part and the controller apart, for an image that runs
    /// them in two tasks ([`fly_step`], [`run_work`]).
    pub fn split(&mut self) -> (&mut CrtpCore, &mut AnyController<f32>) {
        (&mut self.core, &mut self.ctrl)
    }

    /// Writes entry `index` of the flight loop's parameter table
    /// ([`PARAMS`], the same ids as the CRTP table's first entries) as a
    /// client's write is: checked, applied, re-designing only while the
    /// motors are off. Returns the value in force.
    pub fn write_param(&mut self, index: usize, value: f32) -> Result<f32, Refusal> {
        let param = PARAMS.get(index).ok_or(Refusal::Unknown)?;
        if let Written::Later = self.core.param_write(index, value, Reply::Caller)? {
            if let Some((r, _)) = self.run_pending() {
                r?;
            }
        }
        Ok((param.get)(self.core.core.settings()))
    }

    /// One IMU sample taken at `t_us` with the fixes of the host's own
    /// position source: [`CrtpCore::imu_begin`], [`fly_step`], then the
    /// log blocks due sampled ([`CrtpCore::sample_logs`]).
    /// Returns the inputs to apply (zero: motors off).
    pub fn imu_step<C: CycleClock>(&mut self, t_us: u64, imu: &ImuSample, fixes: &[Fix], clock: &C) -> Vector4<f32> {
        let step = self.core.imu_begin(t_us, Some(imu), fixes, clock);
        let u = fly_step(&mut fc_loop::Exclusive(&mut self.core), &mut self.ctrl, step, clock);
        self.core.sample_logs();
        u
    }

    /// Handles one packet; answers go to `out`, a re-designing write's
    /// once its design (run here) is done.
    pub fn handle<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<(), S::Error> {
        self.core.handle(p, out)?;
        self.run_pending();
        if let Some(r) = self.core.take_persist() {
            r.answer(out)?;
        }
        self.core.send_queued(out)
    }

    /// Runs the controller work a packet queued, if any.
    fn run_pending(&mut self) -> Option<(Result<(), Refusal>, Option<FromFc>)> {
        let work = self.core.take_work()?;
        Some(run_work(&mut fc_loop::Exclusive(&mut self.core), &mut self.ctrl, work))
    }
}

/// Where controller work stands (one at a time).
#[derive(Debug, Clone, Copy)]
#[allow(
    clippy::large_enum_variant,
    reason = "no allocation: the work is held in place, one at a time"
)]
enum WorkState {
    Idle,
    Queued(ControllerWork),
    Running,
}

/// The CRTP vehicle without its controller (see the module's
/// documentation): what the link's and the IMU's tasks share.
pub struct CrtpCore {
    core: Loop,
    /// Controller work asked for and not yet done.
    work: WorkState,
    /// The answer of a re-designing parameter write, sent before the console.
    reply: Option<Packet>,
    /// A persistent-parameter request, for the link's owner to answer.
    persist: Option<PersistRequest>,
    defaults: Settings,
    mixer: Option<Mixer<f32>>,
    armed: bool,
    tumbled: bool,
    locked: bool,
    mode: Mode,
    log: LogBlocks,
    console: heapless::Deque<Packet, CONSOLE_QUEUE>,
    /// Log blocks sampled at their step, waiting for the link.
    sampled: heapless::Deque<Packet, LOG_QUEUE>,
    /// Time of the last IMU step, µs.
    now_us: u64,
    seq: u32,
    /// Inputs of the last step `[U1 N, U2 N, U3 N, U4 N·m]` (zero: motors off).
    u: Vector4<f32>,
    /// A position source with heading has been seen (pose, or the host's).
    heading_seen: bool,
    /// The battery voltage the radio chip last reported, V; `None` until
    /// it reports one (no reading is not a full battery).
    vbat_v: Option<f32>,
    pm_state: i8,
    counters: CrtpCounters,
    /// Every IMU sample checked, the last good one held.
    imu: ImuGuard,
    /// The board's sensors as it started them (`Ok`: the simulator's).
    sensors: Result<(), SensorDown>,
    /// A failsafe descent began in this silence of the IMU.
    failsafe: bool,
    /// The board's barometer as a height fix, and the fixes it gave.
    baro: Barometer,
    baro_fixes: u32,
}

impl CrtpCore {
    /// The vehicle's shared part with nothing designed yet (motors off
    /// until [`CrtpVehicle::start`] succeeds).
    pub fn unstarted(settings: Settings) -> Self {
        Self {
            core: Loop::unstarted_with(FcConfig::default(), settings),
            work: WorkState::Idle,
            reply: None,
            persist: None,
            defaults: settings,
            mixer: None,
            armed: false,
            tumbled: false,
            locked: false,
            mode: Mode::Idle,
            log: LogBlocks::new(),
            console: heapless::Deque::new(),
            sampled: heapless::Deque::new(),
            now_us: 0,
            seq: 0,
            u: Vector4::zeros(),
            heading_seen: false,
            vbat_v: None,
            pm_state: 0,
            counters: CrtpCounters::default(),
            imu: ImuGuard::new(),
            sensors: Ok(()),
            failsafe: false,
            baro: Barometer::new(),
            baro_fixes: 0,
        }
    }

    /// What the board's sensors did at start-up (a board without sensors
    /// of its own, flying a simulator's, leaves it `Ok`): arming is refused
    /// while one is down, naming it.
    pub fn set_sensors(&mut self, r: Result<(), SensorDown>) {
        self.sensors = r;
    }

    /// The IMU samples that were not good, by kind
    /// ([`crate::supervisor::ImuGuard`]).
    pub fn imu_counters(&self) -> ImuCounters {
        self.imu.counters()
    }

    /// A failsafe descent is under way (the IMU went silent in flight).
    pub fn failsafe(&self) -> bool {
        self.failsafe
    }

    /// The board's barometer read `alt_m` (m above sea level: the
    /// BMP388's pressure through [`fc_loop::baro::pressure_altitude_m`]) at
    /// `t_us`: fused as a height fix before the next IMU step, at most at
    /// 50 Hz, its first reading referenced to the estimated height then
    /// ([`Barometer`]). `true` if it was fused; a reading that is not a
    /// measurement, or one before the estimator has a position, is not.
    pub fn baro(&mut self, t_us: u64, alt_m: f32) -> bool {
        let est_down_m = self.core.navigator().estimate().map(|e| e.pos_ned_m[2]);
        match self.baro.fix(t_us, alt_m, est_down_m) {
            Some(fix) => {
                self.core.push_fix(&fix);
                self.baro_fixes = self.baro_fixes.wrapping_add(1);
                true
            }
            None => false,
        }
    }

    /// Barometer fixes fused since start-up ([`CrtpCore::baro`]).
    pub fn baro_fixes(&self) -> u32 {
        self.baro_fixes
    }

    /// A parameter write from the board's simulator (our protocol's
    /// `ParamSet` of entry `index` of [`PARAMS`], the same ids as the CRTP
    /// table's first entries), as a client's write is: checked, applied,
    /// re-designing only while the motors are off. Returns the answer, or
    /// `None` when a re-design was queued ([`CrtpCore::take_work`]), whose
    /// answer [`CrtpCore::work_done`] gives.
    pub fn sim_param(&mut self, index: u16, value: f32) -> Option<FromFc> {
        let r = match PARAMS.get(usize::from(index)) {
            None => Err(Refusal::Unknown),
            Some(_) => self.param_write(usize::from(index), value, Reply::Sim(index)),
        };
        match r {
            Ok(Written::Later) => None,
            Ok(Written::Now) => Some(fc_loop::param_answer(self.core.settings(), index, None)),
            Err(e) => Some(fc_loop::param_answer(self.core.settings(), index, Some(e))),
        }
    }

    /// The controller work a packet asked for, handed to the controller's
    /// side (which answers with [`CrtpCore::work_done`]); until then no
    /// other work is taken and parameter writes are refused as busy.
    pub fn take_work(&mut self) -> Option<ControllerWork> {
        match self.work {
            WorkState::Queued(w) => {
                self.work = WorkState::Running;
                Some(w)
            }
            _ => None,
        }
    }

    /// Records the end of `work` with its result `r`: a failed take-off
    /// reset (none fails) leaves the motors idle; a re-designing write takes the new
    /// mixer and is answered (a CRTP client through the downlink, before
    /// the console; the simulator by the returned message).
    pub fn work_done(&mut self, work: &ControllerWork, r: Result<(), Refusal>) -> Option<FromFc> {
        self.work = WorkState::Idle;
        match (work, r) {
            (ControllerWork::Reset, Ok(())) => {
                self.counters.handled = self.counters.handled.wrapping_add(1);
                None
            }
            (ControllerWork::Reset, Err(_)) => {
                self.counters.refused = self.counters.refused.wrapping_add(1);
                self.mode = Mode::Idle;
                self.say(format_args!("controller reset failed"));
                None
            }
            (ControllerWork::Param { reply, .. }, r) => {
                let r = r.and_then(|()| {
                    self.mixer = Some(self.core.settings().mixer()?);
                    Ok(())
                });
                match reply {
                    Reply::Crtp(request) => {
                        if r.is_ok() {
                            self.counters.handled = self.counters.handled.wrapping_add(1);
                        } else {
                            self.counters.refused = self.counters.refused.wrapping_add(1);
                        }
                        self.reply = Some(self.written_reply(request, r.err()));
                        None
                    }
                    Reply::Sim(index) => Some(fc_loop::param_answer(self.core.settings(), *index, r.err())),
                    Reply::Caller => None,
                }
            }
        }
    }

    /// Controller work is queued or running.
    pub fn busy(&self) -> bool {
        !matches!(self.work, WorkState::Idle)
    }

    /// Armed.
    pub fn armed(&self) -> bool {
        self.armed
    }

    /// The motors turn (armed and flying a set-point).
    pub fn flying(&self) -> bool {
        self.armed && self.mode != Mode::Idle
    }

    /// The flight loop (estimator, set-point, counters).
    pub fn core(&self) -> &Loop {
        &self.core
    }

    /// What was done with the packets.
    pub fn counters(&self) -> CrtpCounters {
        self.counters
    }

    /// Counts a datagram that was not a packet (the transport's refusal).
    pub fn count_malformed(&mut self, e: CrtpError) {
        self.counters.count(e);
    }

    /// The inputs of the last step `[U1 N, U2 N, U3 N, U4 N·m]`, zero
    /// while the motors are off.
    pub fn output(&self) -> Vector4<f32> {
        self.u
    }

    /// The motor commands of the last step (the mixer's unit; zero off),
    /// mixed when asked (the log, a test), not in the step.
    pub fn motors(&self) -> [f32; 4] {
        // Off, the step's inputs are zero: so are their commands.
        self.mixer.as_ref().map_or([0.0; 4], |m| m.commands(&self.u).commands)
    }

    /// The mixer of the parameters in force (`None` until started): the
    /// rotors' thrusts of a step's inputs, for a board's motors.
    pub fn mixer(&self) -> Option<&Mixer<f32>> {
        self.mixer.as_ref()
    }

    /// The battery voltage the nRF51 last reported, V; 0 until it reports
    /// one (the vehicle does not arm before: [`Self::battery_reported`]).
    pub fn battery_v(&self) -> f32 {
        self.vbat_v.unwrap_or(0.0)
    }

    /// Whether the nRF51 (or the simulator, in process) has reported the
    /// battery since boot.
    pub fn battery_reported(&self) -> bool {
        self.vbat_v.is_some()
    }

    /// The battery: voltage, V, and the Crazyflie's `pm.state` (0 on
    /// battery, 1 charging, 2 charged, 3 low, 4 shut down).
    pub fn set_battery(&mut self, vbat_v: f32, state: i8) {
        if vbat_v.is_finite() {
            self.vbat_v = Some(vbat_v);
        }
        self.pm_state = state;
    }

    /// One IMU sample taken at `t_us` (`None`: the board's driver had
    /// none) with the fixes of the host's own position source (`heading`:
    /// they carry one), the IMU task's half: the sample checked (a bad or
    /// missing one replaced by the last good one,
    /// [`crate::supervisor::ImuGuard`]), the set-point of this instant, one
    /// estimator step, the supervisor's checks; returns the controller's
    /// step ([`fly_step`] flies it).
    pub fn imu_begin<C: CycleClock>(
        &mut self,
        t_us: u64,
        imu: Option<&ImuSample>,
        fixes: &[Fix],
        clock: &C,
    ) -> ImuStep {
        if t_us < self.now_us {
            // A host that started again: a new time line.
            self.core.open_session();
            self.imu.restart();
            self.baro.reset();
        }
        let (sample, _) = self.imu.take(t_us, imu);
        // The interval a velocity set-point moves over (at most 0.1 s).
        let dt_s = (t_us.saturating_sub(self.now_us) as f32 * 1e-6).min(0.1);
        self.now_us = t_us;
        for f in fixes {
            self.heading_seen |= f.yaw_rad.is_some();
            self.core.push_fix(f);
        }
        let sp = self.setpoint_now(t_us, dt_s);
        if let Some(sp) = sp {
            self.core.set_setpoint(&sp);
        }
        self.seq = self.seq.wrapping_add(1);
        // Nothing to step on before the first good sample.
        let job = sample
            .and_then(|imu| self.core.imu_job(self.seq, t_us, &imu, clock, t_us))
            .map(|job| match job {
                // The estimator's state goes out in log blocks, not with every
                // step's answer (our protocol's `Nav`): not built.
                Job::Step(step) => Job::Step(fc_loop::Step { nav: false, ..step }),
                other => other,
            });
        // The controller changes nothing the supervisor reads.
        self.supervise(t_us);
        ImuStep {
            job,
            setpoint: sp.is_some(),
        }
    }

    /// The end of an IMU step whose controller answered `u` (`None`: no
    /// answer): the inputs to apply, zero unless armed and flying a
    /// set-point.
    pub fn imu_end(&mut self, step: &ImuStep, u: Option<[f32; 4]>) -> Vector4<f32> {
        let on = self.armed && self.mode != Mode::Idle && step.setpoint;
        self.u = match u {
            Some(u) if on => Vector4::from(u),
            _ => Vector4::zeros(),
        };
        self.u
    }

    /// The set-point to fly at `t_us`, `dt_s` after the last step (the mode
    /// advanced: hand-over, watchdog, velocity), `None` while idle.
    fn setpoint_now(&mut self, t_us: u64, dt_s: f32) -> Option<Setpoint<f32>> {
        if let Mode::Generic {
            sp,
            last_us,
            handover_us,
        } = self.mode
        {
            let age_ms = t_us.saturating_sub(last_us) / 1000;
            if handover_us.is_some_and(|h| t_us >= h) {
                self.hold_from(&Reference::from(&sp), t_us);
            } else if age_ms > SETPOINT_STOP_MS {
                self.mode = Mode::Idle;
                self.say(format_args!("set-points stopped: motors off"));
            }
        }
        let r = match &mut self.mode {
            Mode::Idle => return None,
            Mode::High { seg, .. } => seg.eval(t_us),
            Mode::Generic { sp, last_us, .. } => {
                if t_us.saturating_sub(*last_us) / 1000 > SETPOINT_LEVEL_MS {
                    // Level and still where it is.
                    sp.vel_ned_mps = Vector3::zeros();
                    sp.acc_ned_mps2 = Vector3::zeros();
                    sp.yaw_rate_radps = 0.0;
                } else {
                    // A velocity set-point moves its position.
                    sp.pos_ned_m += sp.vel_ned_mps * dt_s;
                    sp.yaw_rad += sp.yaw_rate_radps * dt_s;
                }
                Reference::from(&*sp)
            }
        };
        Some(r.setpoint())
    }

    /// Holds `from` (brought to rest over half a second) under the
    /// high-level commander.
    fn hold_from(&mut self, from: &Reference, t_us: u64) {
        self.mode = match Segment::plan(t_us, from, from.pos_ned_m, from.yaw_rad, 0.5) {
            Ok(seg) => Mode::High { seg, landing: false },
            Err(_) => Mode::Idle,
        };
    }

    /// The IMU's silence, tumble detection and the end of a landing.
    fn supervise(&mut self, t_us: u64) {
        if !self.imu.silent() {
            self.failsafe = false;
        } else if self.flying() && !matches!(self.mode, Mode::High { landing: true, .. }) {
            // Every command while silent is overruled by the descent.
            self.failsafe_descent(t_us);
        }
        let Some(est) = self.core.navigator().estimate() else {
            return;
        };
        let q = est.att;
        // The body z axis' down component: cos(tilt).
        let cos_tilt = 1.0 - 2.0 * (q[1] * q[1] + q[2] * q[2]);
        if self.flying() && cos_tilt < COS_TUMBLE_TILT {
            self.tumbled = true;
            self.mode = Mode::Idle;
            self.say(format_args!("tumbled: motors off"));
        }
        if let Mode::High { seg, landing: true } = self.mode {
            if seg.finished(t_us) && (est.pos_ned_m[2] - seg.goal().pos_ned_m[2]).abs() < LANDED_M {
                self.mode = Mode::Idle;
                self.say(format_args!("landed: motors off"));
            }
        }
    }

    /// Straight down from where the vehicle is flying to the frame's z = 0
    /// (the floor of a motion-capture or Lighthouse frame) at
    /// [`FAILSAFE_DESCENT_MPS`], landed as a landing is.
    fn failsafe_descent(&mut self, t_us: u64) {
        if !self.failsafe {
            self.failsafe = true;
            let ms = IMU_TIMEOUT_US / 1000;
            self.say(format_args!("IMU silent for more than {ms} ms: failsafe descent"));
        }
        let here = self.reference();
        let height_m = (-here.pos_ned_m[2]).max(0.0);
        let goal = Vector3::new(here.pos_ned_m[0], here.pos_ned_m[1], 0.0);
        let dur_s = (height_m / FAILSAFE_DESCENT_MPS).max(0.5);
        self.mode = match Segment::plan(t_us, &here, goal, here.yaw_rad, dur_s) {
            Ok(seg) => Mode::High { seg, landing: true },
            Err(_) => Mode::Idle,
        };
    }

    /// What is flown now, as a reference (the estimate at rest when idle).
    fn reference(&self) -> Reference {
        match &self.mode {
            Mode::High { seg, .. } => seg.eval(self.now_us),
            Mode::Generic { sp, .. } => Reference::from(sp),
            Mode::Idle => match self.core.navigator().estimate() {
                Some(e) => Reference::at_rest(e.pos_ned_m, e.euler()[2]),
                None => Reference::at_rest(Vector3::zeros(), 0.0),
            },
        }
    }

    /// Queues a console line (in as many packets as it takes).
    fn say(&mut self, text: core::fmt::Arguments) {
        let Ok(p) = Packet::new(Port::Console, 0, &[]) else {
            return;
        };
        let mut line = Line {
            p,
            queue: &mut self.console,
        };
        let _ = line.write_fmt(text);
        let _ = line.write_str("\n");
        line.push();
    }

    /// Samples the log blocks due at the last step's time (their values and
    /// that time, in ms): called once per step, after it is flown
    /// ([`CrtpVehicle::imu_step`]; an image's controller task), so a block's
    /// stamps follow its grid whenever the link sends it.
    pub fn sample_logs(&mut self) {
        if !self.log.any_due(self.now_us) {
            return;
        }
        let values = self.log_values();
        while let Some(p) = self
            .log
            .next_due(self.now_us, |v| values.get(usize::from(v)).copied().unwrap_or(0.0))
        {
            if self.sampled.is_full() {
                self.sampled.pop_front();
            }
            let _ = self.sampled.push_back(p);
        }
    }

    /// Sends what is waiting: a re-designing write's answer, console lines,
    /// then the log blocks sampled ([`CrtpCore::sample_logs`]).
    pub fn poll<S: CrtpSink>(&mut self, out: &mut S) -> Result<(), S::Error> {
        self.send_queued(out)?;
        while let Some(p) = self.sampled.pop_front() {
            out.send(&p)?;
        }
        Ok(())
    }

    /// The log variables' values now, in [`LOG_VARS`] order.
    pub fn log_values(&self) -> [f32; LOG_VARS.len()] {
        let mut v = [0.0; LOG_VARS.len()];
        let deg = 180.0 / core::f32::consts::PI;
        if let Some(e) = self.core.navigator().estimate() {
            let p = frames::cf_from_ned(&e.pos_ned_m);
            let vel = frames::cf_from_ned(&e.vel_ned_mps);
            let rpy = e.euler();
            let att = [rpy[0] * deg, rpy[1] * deg, frames::heading_from_cf_yaw(rpy[2]) * deg];
            v[0..3].copy_from_slice(&p);
            v[3..6].copy_from_slice(&vel);
            v[6..9].copy_from_slice(&att);
            v[9..12].copy_from_slice(&att);
            let cov = self.core.navigator().estimator().covariance();
            for i in 0..3 {
                v[13 + i] = cov[(i, i)];
            }
        }
        let u1_max = 4.0
            * self.core.vehicle().kf_ns2
            * self.core.vehicle().omega_max_radps
            * self.core.vehicle().omega_max_radps;
        v[12] = (self.u[0] / u1_max).clamp(0.0, 1.0) * 65535.0;
        v[16] = self.battery_v();
        v[17] = f32::from(self.pm_state);
        let motors = self.motors();
        for i in 0..4 {
            v[18 + i] = motors[i].clamp(0.0, 1.0) * 65535.0;
        }
        v[22] = f32::from(u8::from(self.can_fly()));
        v[23] = f32::from(u8::from(self.armed));
        v[24] = f32::from(self.supervisor_bits());
        let target = frames::cf_from_ned(&self.core.setpoint().pos_ned_m);
        v[25..28].copy_from_slice(&target);
        v
    }

    fn can_fly(&self) -> bool {
        self.core.navigator().mode() == NavMode::Navigating
            && !self.tumbled
            && !self.locked
            && self.sensors.is_ok()
            && self.vbat_v.is_some_and(|v| v >= BATTERY_FLOOR_V)
    }

    /// The supervisor's state bits (cflib's `Supervisor.STATES` order).
    pub fn supervisor_bits(&self) -> u16 {
        let high = matches!(self.mode, Mode::High { .. });
        let finished = match self.mode {
            Mode::High { seg, .. } => seg.finished(self.now_us),
            _ => true,
        };
        let bits = [
            self.can_fly() && !self.armed,
            self.armed,
            false,
            self.can_fly(),
            self.flying(),
            self.tumbled,
            self.locked,
            self.tumbled,
            high,
            finished,
            false,
        ];
        bits.iter()
            .enumerate()
            .fold(0, |acc, (i, &b)| acc | (u16::from(b) << i))
    }

    /// Arms (if the supervisor allows) or disarms; the answer is whether it
    /// did, and whether it is armed now.
    fn request_arming(&mut self, arm: bool) -> bool {
        if !arm {
            self.armed = false;
            self.mode = Mode::Idle;
            self.say(format_args!("disarmed"));
            return true;
        }
        if self.armed {
            return true;
        }
        if let Err(down) = self.sensors {
            self.say(format_args!("arming refused: {down}"));
            return false;
        }
        match self.vbat_v {
            None => {
                self.say(format_args!("arming refused: no battery reading yet"));
                return false;
            }
            Some(v) if v < BATTERY_FLOOR_V => {
                self.say(format_args!(
                    "arming refused: battery {v:.2} V below {BATTERY_FLOOR_V:.2} V"
                ));
                return false;
            }
            Some(_) => {}
        }
        let why = match self.core.navigator().mode() {
            _ if self.locked => Some("locked: restart"),
            _ if self.tumbled => Some("tumbled: recover"),
            NavMode::Aligning => Some("estimator aligning"),
            NavMode::Failsafe => Some("estimator failsafe"),
            NavMode::Navigating if self.mixer.is_none() => Some("not started"),
            NavMode::Navigating => None,
        };
        if let Some(why) = why {
            self.say(format_args!("arming refused: {why}"));
            return false;
        }
        self.armed = true;
        self.mode = Mode::Idle;
        self.say(format_args!("armed"));
        true
    }

    /// Starts flying `mode` from idle: the controller's state forgotten (no
    /// state wound up on the ground; [`ControllerWork::Reset`]).
    fn take_control(&mut self) -> bool {
        if !self.armed {
            self.say(format_args!("not armed"));
            return false;
        }
        if self.busy() {
            self.say(format_args!("controller design under way"));
            return false;
        }
        if self.mode == Mode::Idle {
            self.work = WorkState::Queued(ControllerWork::Reset);
        }
        true
    }

    /// Handles one packet; answers go to `out`.
    pub fn handle<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<(), S::Error> {
        if p.is_null() {
            self.counters.null = self.counters.null.wrapping_add(1);
            return out.send(&Packet::NULL);
        }
        let was_busy = self.busy();
        let result = match Port::from_number(p.port()) {
            Some(Port::Link) => self.on_link(p, out),
            Some(Port::Platform) => self.on_platform(p, out),
            Some(Port::Log) => self.on_log(p, out),
            Some(Port::Param) => self.on_param(p, out),
            Some(Port::Mem) => self.on_mem(p, out),
            Some(Port::HighLevel) => Ok(self.on_high_level(p)),
            Some(Port::Generic) => Ok(self.on_generic(p)),
            Some(Port::Commander) => Ok(self.on_legacy_commander(p)),
            Some(Port::Localization) => Ok(self.on_localization(p)),
            Some(Port::Supervisor) => self.on_supervisor(p, out),
            Some(Port::Console) => Ok(Err(unsupported(p))),
            None => Ok(Err(CrtpError::NoSuchPort(p.port()))),
        }?;
        let deferred = matches!(self.work, WorkState::Queued(_)) && !was_busy;
        match result {
            // Counted when its work is done (`work_done`).
            Ok(()) if deferred => {}
            Ok(()) => self.counters.handled = self.counters.handled.wrapping_add(1),
            Err(e) => self.counters.count(e),
        }
        // Console lines the packet caused go out at once.
        self.send_queued(out)
    }

    /// The persistent-parameter request a packet left, if any: its owner
    /// answers it ([`PersistRequest::answer`]) with the storage it has.
    pub fn take_persist(&mut self) -> Option<PersistRequest> {
        self.persist.take()
    }

    /// Sends a re-designing write's answer, then the console lines.
    pub fn send_queued<S: CrtpSink>(&mut self, out: &mut S) -> Result<(), S::Error> {
        if let Some(r) = self.reply.take() {
            out.send(&r)?;
        }
        while let Some(c) = self.console.pop_front() {
            out.send(&c)?;
        }
        Ok(())
    }

    fn on_link<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        match p.channel() {
            0 => out.send(p)?,
            1 => {
                let mut name = [0u8; crate::MAX_PAYLOAD];
                name[..18].copy_from_slice(b"Bitcraze Crazyflie");
                out.send(&reply(Port::Link, 1, &name))?;
            }
            2 => {}
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    fn on_platform<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        match (p.channel(), cmd) {
            (0, 0) | (0, 3) => {}
            (0, 1) => {
                let Some(&arm) = d.get(1) else {
                    return Ok(Err(short(p)));
                };
                let ok = self.request_arming(arm != 0);
                out.send(&reply(Port::Platform, 0, &[1, u8::from(ok), u8::from(self.armed)]))?;
            }
            (0, 2) => {
                let ok = self.recover();
                out.send(&reply(Port::Platform, 0, &[2, u8::from(ok), u8::from(!self.tumbled)]))?;
            }
            (1, 0) => {
                let mut b = [0u8; 5];
                b[1..].copy_from_slice(&crate::PROTOCOL_VERSION.to_le_bytes());
                out.send(&reply(Port::Platform, 1, &b))?;
            }
            (1, 1) | (1, 2) => {
                let text = if cmd == 1 { FIRMWARE_VERSION } else { DEVICE_TYPE_NAME };
                let mut r = reply(Port::Platform, 1, &[cmd]);
                let _ = r.extend(&text.as_bytes()[..text.len().min(r.room())]);
                out.send(&r)?;
            }
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    fn recover(&mut self) -> bool {
        if self.locked || self.flying() {
            return false;
        }
        self.tumbled = false;
        true
    }

    fn on_supervisor<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        let bits = self.supervisor_bits();
        match (p.channel(), cmd) {
            (0, 0x0C) => {
                let b = bits.to_le_bytes();
                out.send(&reply(Port::Supervisor, 0, &[0x8C, b[0], b[1]]))?;
            }
            (0, 0x01..=0x0B) => {
                let bit = (bits >> (cmd - 1)) & 1;
                out.send(&reply(Port::Supervisor, 0, &[0x80 | cmd, bit as u8]))?;
            }
            (1, 0x01) => {
                let Some(&arm) = d.get(1) else {
                    return Ok(Err(short(p)));
                };
                let ok = self.request_arming(arm != 0);
                out.send(&reply(Port::Supervisor, 1, &[0x81, u8::from(ok), u8::from(self.armed)]))?;
            }
            (1, 0x02) => {
                let ok = self.recover();
                out.send(&reply(
                    Port::Supervisor,
                    1,
                    &[0x82, u8::from(ok), u8::from(!self.tumbled)],
                ))?;
            }
            (1, 0x03) => self.emergency_stop(),
            (1, 0x04) => {}
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    /// Motors off and locked until restarted, as the Crazyflie's emergency stop.
    fn emergency_stop(&mut self) {
        self.mode = Mode::Idle;
        self.armed = false;
        self.locked = true;
        self.say(format_args!("emergency stop: locked"));
    }

    fn on_log<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        match p.channel() {
            0 => match cmd {
                toc::CMD_GET_INFO_V2 => {
                    let crc = toc::crc(LOG_VARS.iter().map(|v| (v.kind, log_name(v))));
                    let extra = [log::MAX_BLOCKS as u8, log::MAX_OPS as u8];
                    if let Ok(r) = toc::info_packet(Port::Log, LOG_VARS.len() as u16, crc, &extra) {
                        out.send(&r)?;
                    }
                }
                toc::CMD_GET_ITEM_V2 => {
                    let Some(id) = u16_at(d, 1) else {
                        return Ok(Err(short(p)));
                    };
                    let r = match LOG_VARS.get(usize::from(id)) {
                        Some(v) => toc::item_packet(Port::Log, id, v.kind, &log_name(v)).unwrap_or(Packet::NULL),
                        None => toc::no_item_packet(Port::Log),
                    };
                    out.send(&r)?;
                }
                _ => return Ok(Err(unsupported(p))),
            },
            1 => {
                let id = d.get(1).copied().unwrap_or(0);
                let vars = LOG_VARS.len() as u16;
                let code = match cmd {
                    2 => self.log.delete(id),
                    3 => match d.get(2) {
                        Some(&tens) => self.log.start(id, u16::from(tens) * 10, self.now_us),
                        None => log::ENOEXEC,
                    },
                    4 => self.log.stop(id),
                    5 => {
                        self.log.reset();
                        0
                    }
                    6 if d.len() >= 2 => self.log.create(id, &d[2..], vars),
                    7 if d.len() >= 2 => self.log.append(id, &d[2..], vars),
                    8 => match u16_at(d, 2) {
                        Some(ms) => self.log.start(id, ms, self.now_us),
                        None => log::ENOEXEC,
                    },
                    _ => log::ENOEXEC,
                };
                if let Ok(r) = log::control_reply(cmd, id, code) {
                    out.send(&r)?;
                }
                if code == log::ENOEXEC {
                    return Ok(Err(unsupported(p)));
                }
            }
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    /// Parameter `id`'s value in force.
    fn param_value(&self, id: usize) -> Option<f32> {
        let s = self.core.settings();
        let (_, _, extra) = param_entry(id)?;
        Some(match extra {
            None => (PARAMS[id].get)(s),
            Some(Extra::ResetEstimation) => 0.0,
            Some(Extra::Controller) => (PARAMS[CTL_ID].get)(s),
            Some(Extra::Estimator) => 2.0,
            Some(Extra::EnHighLevel) => 1.0,
            Some(Extra::Alias(i)) => (PARAMS[i].get)(s),
            Some(Extra::Deck) => 0.0,
        })
    }

    /// Parameter `id`'s value at boot.
    fn param_default(&self, id: usize) -> Option<f32> {
        let (_, _, extra) = param_entry(id)?;
        Some(match extra {
            None => (PARAMS[id].get)(&self.defaults),
            Some(Extra::Controller) => (PARAMS[CTL_ID].get)(&self.defaults),
            Some(Extra::Alias(i)) => (PARAMS[i].get)(&self.defaults),
            Some(_) => self.param_value(id)?,
        })
    }

    /// Writes parameter `id`: checked, applied (re-designs only while the
    /// motors are off; a re-design is queued for the controller's side,
    /// and `reply` answered when it is done). Refused while other
    /// controller work is under way.
    fn param_write(&mut self, id: usize, value: f32, reply: Reply) -> Result<Written, Refusal> {
        let (_, _, extra) = param_entry(id).ok_or(Refusal::Unknown)?;
        if self.busy() {
            return Err(Refusal::Busy);
        }
        let index = match extra {
            None => id,
            Some(Extra::Controller) => CTL_ID,
            Some(Extra::Alias(i)) => i,
            Some(Extra::ResetEstimation) if value == 0.0 => return Ok(Written::Now),
            Some(Extra::ResetEstimation) if self.flying() => return Err(Refusal::Armed),
            Some(Extra::ResetEstimation) => {
                self.core.open_session();
                self.heading_seen = false;
                self.say(format_args!("estimator reset"));
                return Ok(Written::Now);
            }
            Some(Extra::Estimator) if value == 2.0 => return Ok(Written::Now),
            Some(Extra::EnHighLevel) if value == 1.0 => return Ok(Written::Now),
            // Read-only: the value in force, 0, is the only one taken.
            Some(Extra::Deck) if value == 0.0 => return Ok(Written::Now),
            Some(_) => return Err(Refusal::Range { lo: value, hi: value }),
        };
        let plan = self.core.plan_param(index, value, !self.flying())?;
        if let ParamPlan::Set(next) | ParamPlan::Redesign(next) = &plan {
            // The mixer's settings checked before anything is taken.
            next.mixer()?;
        }
        match self.core.apply_unless_design(plan) {
            Some(next) => {
                self.work = WorkState::Queued(ControllerWork::Param { next, reply });
                Ok(Written::Later)
            }
            None => {
                self.mixer = Some(self.core.settings().mixer()?);
                Ok(Written::Now)
            }
        }
    }

    /// The answer to the parameter write `request` (by id on channel 2:
    /// the value in force; by name: its status), refused for `refused`
    /// (said on the console) or not.
    fn written_reply(&mut self, request: &Packet, refused: Option<Refusal>) -> Packet {
        let d = request.payload();
        if request.channel() == 3 {
            return set_by_name_reply(request, if refused.is_some() { log::ENOEXEC } else { 0 });
        }
        let id = u16_at(d, 0).map_or(usize::MAX, usize::from);
        if let (Some(why), Some((name, _, _))) = (refused, param_entry(id)) {
            self.say(format_args!("{}.{}: {}", name.group, name.name, why));
        }
        let mut r = reply(Port::Param, 2, &d[..2.min(d.len())]);
        // The value in force, changed or not.
        let now = self.param_value(id).unwrap_or(f32::NAN);
        self.put_value(&mut r, id, now);
        r
    }

    fn on_param<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        let d = p.payload();
        match p.channel() {
            0 => match d.first() {
                Some(&toc::CMD_GET_INFO_V2) => {
                    let crc = toc::crc((0..PARAM_COUNT).filter_map(param_entry).map(|(n, t, _)| (t, n)));
                    if let Ok(r) = toc::info_packet(Port::Param, PARAM_COUNT as u16, crc, &[]) {
                        out.send(&r)?;
                    }
                }
                Some(&toc::CMD_GET_ITEM_V2) => {
                    let Some(id) = u16_at(d, 1) else {
                        return Ok(Err(short(p)));
                    };
                    let r = match param_entry(usize::from(id)) {
                        Some((n, t, _)) => toc::item_packet(Port::Param, id, t, &n).unwrap_or(Packet::NULL),
                        None => toc::no_item_packet(Port::Param),
                    };
                    out.send(&r)?;
                }
                _ => return Ok(Err(unsupported(p))),
            },
            1 => {
                let Some(id) = u16_at(d, 0) else {
                    return Ok(Err(short(p)));
                };
                let mut r = reply(Port::Param, 1, &id.to_le_bytes());
                match self.param_value(usize::from(id)) {
                    Some(v) => {
                        let _ = r.extend(&[0]);
                        self.put_value(&mut r, usize::from(id), v);
                    }
                    None => {
                        let _ = r.extend(&[log::ENOENT]);
                    }
                }
                out.send(&r)?;
            }
            2 => {
                let Some(id) = u16_at(d, 0) else {
                    return Ok(Err(short(p)));
                };
                let id = usize::from(id);
                let Some((_, t, _)) = param_entry(id) else {
                    let mut r = reply(Port::Param, 2, &d[..2]);
                    let _ = r.extend(&[log::ENOENT]);
                    out.send(&r)?;
                    return Ok(Err(unsupported(p)));
                };
                if self.busy() {
                    // Not answered: the client repeats its write, and it is
                    // taken once the design under way is done.
                    return Ok(Err(CrtpError::Refused { port: p.port() }));
                }
                let refused = match read_value(t, &d[2..]) {
                    Some(v) => match self.param_write(id, v, Reply::Crtp(*p)) {
                        Ok(Written::Later) => return Ok(Ok(())),
                        Ok(Written::Now) => None,
                        Err(e) => Some(e),
                    },
                    None => Some(Refusal::NotInteger),
                };
                let r = self.written_reply(p, refused);
                out.send(&r)?;
                if refused.is_some() {
                    return Ok(Err(CrtpError::Refused { port: p.port() }));
                }
            }
            3 => return self.on_param_misc(p, out),
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    /// Appends parameter `id`'s value `v` in its type.
    fn put_value(&self, r: &mut Packet, id: usize, v: f32) {
        put_typed(r, param_entry(id).map_or(param_types::FLOAT, |(_, t, _)| t), v);
    }

    fn on_param_misc<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        if cmd == 0 {
            return self.on_set_by_name(p, out);
        }
        let Some(id) = u16_at(d, 1) else {
            return Ok(Err(short(p)));
        };
        let idb = id.to_le_bytes();
        let mut r = reply(Port::Param, 3, &[cmd, idb[0], idb[1]]);
        let index = usize::from(id);
        let known = param_entry(index).is_some();
        // Persistent: the flight parameters (the TOC's extended flag).
        let persistent = index < PARAMS.len();
        match cmd {
            // Extended type: 1, persistent (status 0 first, protocol 11+).
            7 if known => {
                let _ = r.extend(&[0, u8::from(persistent)]);
            }
            8 if known => {
                let _ = r.extend(&[0]);
                let v = self.param_default(index).unwrap_or(0.0);
                self.put_value(&mut r, index, v);
            }
            // Store the value in force, get the state, clear: as the
            // Crazyflie's persistent parameters, answered by the link's
            // owner with its storage ([`CrtpCore::take_persist`]). One at
            // a time: another is not answered (cflib asks again).
            3..=5 if persistent => {
                if self.persist.is_some() {
                    return Ok(Err(CrtpError::Refused { port: p.port() }));
                }
                self.persist = Some(PersistRequest {
                    cmd,
                    id,
                    now: self.param_value(index).unwrap_or(0.0),
                    default: self.param_default(index).unwrap_or(0.0),
                    ty: param_entry(index).map_or(param_types::FLOAT, |(_, t, _)| t),
                });
                return Ok(Ok(()));
            }
            // Not persistent, and unknown ids.
            3..=5 | 7 | 8 => {
                let _ = r.extend(&[log::ENOENT]);
            }
            _ => return Ok(Err(unsupported(p))),
        }
        out.send(&r)?;
        Ok(Ok(()))
    }

    /// `MISC_SETBYNAME`: `[0, group\0, name\0, type, value]`, answered
    /// `[0, group\0, name\0, error]`.
    fn on_set_by_name<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        let d = &p.payload()[1..];
        let mut parts = d.splitn(3, |&b| b == 0);
        let (Some(group), Some(name), Some(rest)) = (parts.next(), parts.next(), parts.next()) else {
            return Ok(Err(short(p)));
        };
        let Some((&t, value)) = rest.split_first() else {
            return Ok(Err(short(p)));
        };
        let id = (0..PARAM_COUNT).find(|&i| param_entry(i).is_some_and(|(n, _, _)| n.is(group, name)));
        if id.is_some() && self.busy() {
            // As a write by id: not answered until the design under way is done.
            return Ok(Err(CrtpError::Refused { port: p.port() }));
        }
        let code = match (id, read_value(t, value)) {
            (None, _) => log::ENOENT,
            // The type as the firmware compares it: without its flags.
            (Some(i), Some(v)) if param_entry(i).is_some_and(|(_, pt, _)| same_type(pt, t)) => {
                match self.param_write(i, v, Reply::Crtp(*p)) {
                    Ok(Written::Later) => return Ok(Ok(())),
                    Ok(Written::Now) => 0,
                    Err(_) => log::ENOEXEC,
                }
            }
            _ => log::ENOEXEC,
        };
        out.send(&set_by_name_reply(p, code))?;
        Ok(if code == 0 {
            Ok(())
        } else {
            Err(CrtpError::Refused { port: p.port() })
        })
    }

    fn on_mem<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<Result<(), CrtpError>, S::Error> {
        match (p.channel(), p.payload().first()) {
            // No memories.
            (0, Some(&1)) => out.send(&reply(Port::Mem, 0, &[1, 0]))?,
            (0, Some(&0)) => out.send(&reply(Port::Mem, 0, &[0, 1]))?,
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    fn on_high_level(&mut self, p: &Packet) -> Result<(), CrtpError> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Err(short(p));
        };
        let here = self.reference();
        match cmd {
            0 => Ok(()),
            3 => {
                self.mode = Mode::Idle;
                Ok(())
            }
            // TAKEOFF_2 / LAND_2: group, height, yaw, use current yaw, duration.
            7 | 8 => {
                let (Some(h), Some(yaw), Some(&cur), Some(dur)) =
                    (f32_at(d, 2), f32_at(d, 6), d.get(10), f32_at(d, 11))
                else {
                    return Err(short(p));
                };
                let yaw = if cur != 0 {
                    here.yaw_rad
                } else {
                    frames::heading_from_cf_yaw(yaw)
                };
                let goal = Vector3::new(here.pos_ned_m[0], here.pos_ned_m[1], -h);
                self.fly_segment(p, &here, goal, yaw, dur, cmd == 8, false)
            }
            // GO_TO (4): group, relative, x, y, z, yaw, duration; GO_TO_2 (12) adds linear.
            4 | 12 => {
                let at = if cmd == 4 { 3 } else { 4 };
                let vals = [
                    f32_at(d, at),
                    f32_at(d, at + 4),
                    f32_at(d, at + 8),
                    f32_at(d, at + 12),
                    f32_at(d, at + 16),
                ];
                let ([Some(x), Some(y), Some(z), Some(yaw), Some(dur)], Some(&rel)) = (vals, d.get(2)) else {
                    return Err(short(p));
                };
                let linear = cmd == 12 && d.get(3).is_some_and(|&l| l != 0);
                let mut goal = frames::ned_from_cf([x, y, z]);
                let mut heading = frames::heading_from_cf_yaw(yaw);
                if rel != 0 {
                    goal += here.pos_ned_m;
                    heading += here.yaw_rad;
                }
                self.fly_segment(p, &here, goal, heading, dur, false, linear)
            }
            _ => {
                self.say(format_args!("HL command {cmd}: unsupported"));
                Err(unsupported(p))
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn fly_segment(
        &mut self,
        p: &Packet,
        from: &Reference,
        goal: Vector3<f32>,
        yaw: f32,
        dur: f32,
        landing: bool,
        linear: bool,
    ) -> Result<(), CrtpError> {
        let planned = if linear {
            Segment::linear(self.now_us, from, goal, yaw, dur)
        } else {
            Segment::plan(self.now_us, from, goal, yaw, dur)
        };
        let seg = match planned {
            Ok(s) => s,
            Err(e) => {
                self.say(format_args!("HL refused: {e}"));
                return Err(CrtpError::BadValue { port: p.port() });
            }
        };
        if !self.take_control() {
            return Err(CrtpError::Refused { port: p.port() });
        }
        self.mode = Mode::High { seg, landing };
        Ok(())
    }

    fn on_generic(&mut self, p: &Packet) -> Result<(), CrtpError> {
        let d = p.payload();
        let Some(&kind) = d.first() else {
            return Err(short(p));
        };
        if p.channel() == 1 {
            // Meta: notify set-point stop, valid for a further u32 ms.
            return match (kind, d.get(1..5)) {
                (0, Some(ms)) => {
                    let ms = u32::from_le_bytes([ms[0], ms[1], ms[2], ms[3]]);
                    if let Mode::Generic { handover_us, .. } = &mut self.mode {
                        *handover_us = Some(self.now_us + u64::from(ms) * 1000);
                    }
                    Ok(())
                }
                (0, None) => Err(short(p)),
                _ => Err(unsupported(p)),
            };
        }
        if p.channel() != 0 {
            return Err(unsupported(p));
        }
        if kind == 0 {
            self.mode = Mode::Idle;
            return Ok(());
        }
        let vals = [f32_at(d, 1), f32_at(d, 5), f32_at(d, 9), f32_at(d, 13)];
        let [Some(a), Some(b), Some(c), Some(e)] = vals else {
            return if matches!(kind, 7 | 8 | 10) {
                Err(short(p))
            } else {
                Err(unsupported(p))
            };
        };
        if ![a, b, c, e].iter().all(|v| v.is_finite()) {
            return Err(CrtpError::BadValue { port: p.port() });
        }
        let here = self.reference();
        let deg = core::f32::consts::PI / 180.0;
        let mut sp = match (kind, self.mode) {
            (_, Mode::Generic { sp, .. }) => sp,
            _ => Setpoint::hold(here.pos_ned_m, here.yaw_rad),
        };
        match kind {
            // Position: x, y, z (m), yaw (deg).
            7 => {
                sp = Setpoint::hold(frames::ned_from_cf([a, b, c]), frames::heading_from_cf_yaw(e * deg));
            }
            // Velocity in the world: vx, vy, vz (m/s), yaw rate (deg/s).
            8 => {
                sp.vel_ned_mps = frames::ned_from_cf([a, b, c]);
                sp.acc_ned_mps2 = Vector3::zeros();
                sp.yaw_rate_radps = -e * deg;
            }
            // Hover: vx, vy in the body frame (m/s), yaw rate (deg/s), height (m).
            10 => {
                let yaw_cf = frames::heading_from_cf_yaw(sp.yaw_rad);
                let (s, co) = (libm::sinf(yaw_cf), libm::cosf(yaw_cf));
                let world = [a * co - b * s, a * s + b * co, 0.0];
                sp.vel_ned_mps = frames::ned_from_cf(world);
                sp.acc_ned_mps2 = Vector3::zeros();
                sp.pos_ned_m[2] = -e;
                sp.yaw_rate_radps = -c * deg;
            }
            _ => return Err(unsupported(p)),
        }
        if !self.armed {
            return Err(CrtpError::Refused { port: p.port() });
        }
        if !matches!(self.mode, Mode::Generic { .. }) && !self.take_control() {
            return Err(CrtpError::Refused { port: p.port() });
        }
        self.mode = Mode::Generic {
            sp,
            last_us: self.now_us,
            handover_us: None,
        };
        Ok(())
    }

    fn on_legacy_commander(&mut self, p: &Packet) -> Result<(), CrtpError> {
        // roll, pitch, yaw rate (f32 each), thrust (u16).
        match u16_at(p.payload(), 12) {
            Some(0) => {
                self.mode = Mode::Idle;
                Ok(())
            }
            Some(_) => Err(unsupported(p)),
            None => Err(short(p)),
        }
    }

    fn on_localization(&mut self, p: &Packet) -> Result<(), CrtpError> {
        let d = p.payload();
        let bad = CrtpError::BadValue { port: p.port() };
        match (p.channel(), d.first()) {
            (0, _) => {
                let (Some(x), Some(y), Some(z)) = (f32_at(d, 0), f32_at(d, 4), f32_at(d, 8)) else {
                    return Err(short(p));
                };
                let mut fix = position_fix([x, y, z]).ok_or(bad)?;
                if !self.heading_seen && self.core.navigator().mode() == NavMode::Aligning {
                    fix.yaw_rad = Some(0.0);
                    fix.yaw_sigma_rad = BOOT_HEADING_SIGMA_RAD;
                }
                self.core.push_fix(&fix);
                Ok(())
            }
            (1, Some(&8)) => {
                let v: [Option<f32>; 7] = core::array::from_fn(|i| f32_at(d, 1 + 4 * i));
                let [Some(x), Some(y), Some(z), Some(qx), Some(qy), Some(qz), Some(qw)] = v else {
                    return Err(short(p));
                };
                let mut fix = position_fix([x, y, z]).ok_or(bad)?;
                let n2 = qx * qx + qy * qy + qz * qz + qw * qw;
                if !(n2.is_finite() && (n2 - 1.0).abs() < 0.1) {
                    return Err(bad);
                }
                fix.yaw_rad = Some(frames::heading_from_cf_yaw(frames::cf_yaw_of_quat(qx, qy, qz, qw)));
                fix.yaw_sigma_rad = EXTPOSE_SIGMA_RAD;
                self.heading_seen = true;
                self.core.push_fix(&fix);
                Ok(())
            }
            (1, Some(&3)) => {
                self.emergency_stop();
                Ok(())
            }
            (1, Some(&4)) => Ok(()),
            (1, None) => Err(short(p)),
            _ => Err(unsupported(p)),
        }
    }
}

/// A position fix from an external position (the Crazyflie's frame, m),
/// `None` unless finite.
fn position_fix(p: [f32; 3]) -> Option<Fix> {
    if !p.iter().all(|v| v.is_finite() && v.abs() <= 1e4) {
        return None;
    }
    let mut f = Fix::EMPTY;
    f.pos_ned_m = Some(frames::ned_from_cf(p));
    f.pos_sigma_m = Vector3::repeat(EXTPOS_SIGMA_M);
    Some(f)
}

/// A log variable's TOC name.
fn log_name(v: &LogVar) -> Name<'static> {
    Name {
        group: v.group,
        name: v.name,
        lower_group: false,
    }
}

/// A parameter value of param type `t` in `b`, as f32.
fn same_type(a: u8, b: u8) -> bool {
    a & param_types::TYPE == b & param_types::TYPE
}

/// Appends `v` to `r` as parameter type `t` (its flags ignored): a byte
/// for `uint8_t`, two little-endian bytes for `uint16_t`, four for `float`.
pub(crate) fn put_typed(r: &mut Packet, t: u8, v: f32) {
    let _ = match t & param_types::TYPE {
        param_types::U8 => r.extend(&[v as u8]),
        param_types::U16 => r.extend(&(v as u16).to_le_bytes()),
        _ => r.extend(&v.to_le_bytes()),
    };
}

/// `[f32]` from the start of `b` as parameter type `t`.
fn read_value(t: u8, b: &[u8]) -> Option<f32> {
    match t & param_types::TYPE {
        param_types::U8 => b.first().map(|&v| f32::from(v)),
        param_types::U16 => b.get(..2).map(|v| f32::from(u16::from_le_bytes([v[0], v[1]]))),
        param_types::FLOAT => f32_at(b, 0),
        _ => None,
    }
}

/// The answer to the `MISC_SETBYNAME` request `request` (`[0, group\0,
/// name\0, type, value]`) with status `code`: `[0, group\0, name\0, code]`.
fn set_by_name_reply(request: &Packet, code: u8) -> Packet {
    let d = request.payload().get(1..).unwrap_or(&[]);
    let mut parts = d.splitn(3, |&b| b == 0);
    let names = match (parts.next(), parts.next()) {
        (Some(group), Some(name)) => (group.len() + name.len() + 2).min(d.len()),
        _ => d.len(),
    };
    let mut r = reply(Port::Param, 3, &[0]);
    let _ = r.extend(&d[..names]);
    let _ = r.extend(&[code]);
    r
}

fn reply(port: Port, channel: u8, payload: &[u8]) -> Packet {
    Packet::new(port, channel, payload).unwrap_or(Packet::NULL)
}

fn unsupported(p: &Packet) -> CrtpError {
    CrtpError::Unsupported {
        port: p.port(),
        channel: p.channel(),
        command: p.payload().first().copied().unwrap_or(0),
    }
}

fn short(p: &Packet) -> CrtpError {
    CrtpError::Short {
        port: p.port(),
        channel: p.channel(),
        len: p.payload().len(),
    }
}
