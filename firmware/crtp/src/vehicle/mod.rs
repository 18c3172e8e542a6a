//! The flight controller behind CRTP: [`CrtpVehicle`] answers cflib and
//! cfclient as a Crazyflie (firmware protocol version 12) does and flies
//! the flight loop ([`fc_loop::Loop`] and its controller) on its own
//! sensors.
//!
//! It is two parts, as the flight loop is: [`CrtpShared`], everything but the
//! controller (the packets, the commander, the supervisor, the loop), and the
//! controller. In-process ([`CrtpVehicle`]) they step together. An image
//! that runs the IMU, the controller and the link at three interrupt
//! priorities keeps them apart: the IMU task takes each sample's estimator
//! half ([`CrtpShared::imu_begin`]), the controller's task flies it
//! ([`fly_step`]) and runs the controller work a packet asked for
//! ([`CrtpShared::take_work`], [`run_work`]) — a take-off's reset, a
//! parameter write that re-designs (answered once it is done) — and the
//! link's task handles packets under short locks of the [`CrtpShared`].
//!
//! Services (port: what), each port in a file of its own under `ports/`
//! (the IMU step in `step.rs`, the image's split in `split.rs`):
//! - link (15): echo (channel 0), "Bitcraze Crazyflie" (source, 1), sink
//!   (2); a null packet is answered with a null packet.
//! - platform (13): protocol version [`crate::PROTOCOL_VERSION`], firmware
//!   version, device type name; the legacy arming and recovery commands.
//! - log (5): TOC v2 of [`LOG_VARS`], blocks ([`crate::log`]).
//! - param (2): TOC v2 of [`fc_loop::params::PARAMS`] (group = the name's
//!   prefix in lower case: `MPC_W_POS` is `mpc.W_POS`), the same
//!   parameters again under the Crazyflie names the table gives them
//!   ([`fc_loop::params::Param::crtp_alias`]), and [`EXTRA_PARAMS`] (the
//!   other Crazyflie names cflib's helpers and examples use); read, write
//!   (answered with the value in force), set by name, default values,
//!   extended types, persistent storage.
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
use crate::toc::{self, Name};
pub use crate::CrtpSink;
use crate::{f32_at, frames, u16_at, u32_at, CrtpCounters, CrtpError, Packet, Port};
use core::borrow::BorrowMut;
use core::fmt::Write as _;
use fc_core::control::AnyController;
use fc_core::control::Setpoint;
use fc_core::estimate::{Fix, ImuSample};
use fc_core::model::airframe::Mixer;
use fc_loop::client::{ClientCommander, CommandRefusal, Takeover};
use fc_loop::commander::{Event, StreamVelocity, Watchdog};
use fc_loop::nav::NavMode;
use fc_loop::params::{crtp_params, ParamType, Refusal, Settings, CRTP_ALIASED, CRTP_ALIASES, CRTP_PARAMS, PARAMS};
use fc_loop::power::Power;
use fc_loop::supervisor::{ImuCounters, SensorDown, BATTERY_FLOOR_V, IMU_TIMEOUT_US};
use fc_loop::{FcConfig, Loop, Mutex};
use fc_proto::FromFc;
use hal_shim::CycleClock;
use nalgebra::{Vector3, Vector4};

mod command;
mod ports;
mod split;
mod step;

pub use crate::value::param_types;
pub use ports::logging::{LogSample, LogVar, LOG_VARS};
pub use ports::param::{param_entry, param_named, Extra, DECK_NAMES, EXTRA_PARAMS, PARAM_COUNT};
pub use split::{fly_step, pass_step, run_work};

/// A generic set-point older than this is held level where it is, ms.
pub const SETPOINT_LEVEL_MS: u64 = 500;
/// A generic set-point older than this stops the motors, ms.
pub const SETPOINT_STOP_MS: u64 = 2000;
/// The watchdog of a stream of generic set-points (the Crazyflie's).
pub const SETPOINT_WATCHDOG: Watchdog = Watchdog {
    level_ms: SETPOINT_LEVEL_MS,
    stop_ms: SETPOINT_STOP_MS,
};
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

/// What a port's handler gives: its sends' error outside (the link's to
/// deal with), and inside what it did with the packet (a refusal is
/// counted, [`CrtpCounters::count`]).
type Handled<E> = Result<Result<(), CrtpError>, E>;

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

/// An IMU step's estimator half ([`CrtpShared::imu_begin`]), for the
/// controller's side ([`fly_step`]).
#[derive(Debug, Clone, Copy)]
pub struct ImuStep {
    /// The loop's step for the controller (`None`: no session, not flown).
    pub job: Option<fc_loop::Step>,
    /// A set-point is flown (the commander, not idle, gave one).
    pub setpoint: bool,
}

/// The flight controller behind CRTP in one piece (see the module's
/// documentation): a [`CrtpShared`] (reached through `Deref`) and its
/// controller, whose work runs at once.
pub struct CrtpVehicle {
    shared: CrtpShared,
    ctrl: AnyController<f32>,
}

impl core::ops::Deref for CrtpVehicle {
    type Target = CrtpShared;
    fn deref(&self) -> &CrtpShared {
        &self.shared
    }
}

impl core::ops::DerefMut for CrtpVehicle {
    fn deref_mut(&mut self) -> &mut CrtpShared {
        &mut self.shared
    }
}

/// The vehicle reached directly: the controller work a locked moment
/// asked for runs before the lock ends (syslink's packets, in-process).
impl Mutex for CrtpVehicle {
    type T = CrtpShared;
    fn lock<R>(&mut self, f: impl FnOnce(&mut CrtpShared) -> R) -> R {
        let r = f(&mut self.shared);
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
            shared: CrtpShared::unstarted(settings),
            ctrl: fc_loop::fallback_controller(settings.vehicle),
        }
    }

    /// The values `MISC_GET_DEFAULT_VALUE` and `persistent_get_state`
    /// report as defaults: the built-in ones, where the vehicle booted with
    /// stored values (by default, the settings it was made with).
    pub fn set_defaults(&mut self, defaults: Settings) {
        self.shared.defaults = defaults;
    }

    /// Reports the decks of `mask` (bit `i`: [`DECK_NAMES`]`[i]`) attached
    /// in their `deck.bc*` flags, as a Crazyflie's deck drivers do once
    /// they have found their deck at boot. Only the flag: nothing here
    /// drives a deck or reads its sensors; a simulator that calls it gives
    /// the vehicle what the deck would stand in for (positions) itself.
    pub fn report_decks(&mut self, mask: u8) {
        self.shared.decks = mask;
    }

    /// Takes the stored values of the persistent parameters that are not
    /// the flight stack's (`ring.effect`) from `store`, each through the
    /// check a write from cflib passes (a value it refuses is left out and
    /// counted: the default stands); the flight parameters are the
    /// settings' ([`fc_loop::params::load`]). How many were taken and
    /// refused; Err only if the store cannot be read.
    pub fn load_stored(&mut self, store: &mut dyn fc_storage::Persist) -> Result<(u16, u16), fc_storage::StoreError> {
        let (mut taken, mut refused) = (0, 0);
        for id in fc_loop::params::CRTP_PARAMS..ports::param::PARAM_COUNT {
            if !ports::param::persistent(id) {
                continue;
            }
            let Some(v) = store.param(id as u16)? else {
                continue;
            };
            match self.shared.param_write(id, v, Reply::Caller) {
                Ok(_) => taken += 1,
                Err(_) => refused += 1,
            }
        }
        Ok((taken, refused))
    }

    /// Checks the settings and designs the controller in place.
    pub fn start(&mut self) -> Result<(), Refusal> {
        fc_loop::start_front_end(&mut self.shared.lp, &mut self.ctrl)
    }

    /// The shared part and the controller apart, for an image that runs
    /// them in two tasks ([`fly_step`], [`run_work`]).
    pub fn split(&mut self) -> (&mut CrtpShared, &mut AnyController<f32>) {
        (&mut self.shared, &mut self.ctrl)
    }

    /// Writes entry `index` of the flight loop's parameter table
    /// ([`PARAMS`], the same ids as the CRTP table's first entries) as a
    /// client's write is: checked, applied, re-designing only while the
    /// motors are off. Returns the value in force.
    pub fn write_param(&mut self, index: usize, value: f32) -> Result<f32, Refusal> {
        let param = crtp_params().get(index).ok_or(Refusal::Unknown)?;
        if let Written::Later = self.shared.param_write(index, value, Reply::Caller)? {
            if let Some((r, _)) = self.run_pending() {
                r?;
            }
        }
        Ok((param.get)(self.shared.lp.settings()))
    }

    /// One IMU sample taken at `t_us` with the fixes of the host's own
    /// position source: [`CrtpShared::imu_begin`], [`fly_step`], then the
    /// log blocks due sampled ([`CrtpShared::sample_logs`]).
    /// Returns the inputs to apply (zero: motors off).
    pub fn imu_step<C: CycleClock>(&mut self, t_us: u64, imu: &ImuSample, fixes: &[Fix], clock: &C) -> Vector4<f32> {
        let step = self.shared.imu_begin(t_us, Some(imu), fixes, clock);
        let power = fly_step(&mut fc_loop::Exclusive(&mut self.shared), &mut self.ctrl, step, clock);
        self.shared.sample_logs();
        power.u
    }

    /// Handles one packet; answers go to `out`, a re-designing write's
    /// once its design (run here) is done.
    pub fn handle<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Result<(), S::Error> {
        self.shared.handle(p, out)?;
        self.run_pending();
        if let Some(r) = self.shared.take_persist() {
            r.answer(out)?;
        }
        self.shared.send_queued(out)
    }

    /// Runs the controller work a packet queued, if any.
    fn run_pending(&mut self) -> Option<(Result<(), Refusal>, Option<FromFc>)> {
        let work = self.shared.take_work()?;
        Some(run_work(
            &mut fc_loop::Exclusive(&mut self.shared),
            &mut self.ctrl,
            work,
        ))
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
pub struct CrtpShared {
    lp: Loop,
    /// Controller work asked for and not yet done.
    work: WorkState,
    /// The answer of a re-designing parameter write, sent before the console.
    reply: Option<Packet>,
    /// A persistent-parameter request, for the link's owner to answer.
    persist: Option<PersistRequest>,
    defaults: Settings,
    /// Arming, the set-point flown and its source, the supervisor: what a
    /// client's commands may do ([`fc_loop::client`]).
    client: ClientCommander,
    log: LogBlocks,
    console: heapless::Deque<Packet, CONSOLE_QUEUE>,
    /// Log blocks sampled at their step, waiting for the link.
    sampled: heapless::Deque<Packet, LOG_QUEUE>,
    /// Time of the last IMU step, µs.
    now_us: u64,
    seq: u32,
    /// Inputs of the last step `[U1 N, U2 N, U3 N, U4 N·m]` (zero: motors off).
    u: Vector4<f32>,
    /// The motor commands of the last step (the mixer's unit; zero: off).
    motors: [f32; 4],
    /// A position source with heading has been seen (pose, or the host's).
    heading_seen: bool,
    /// `led.bitmask` as last written (0 at boot): kept and read back; no
    /// LED here to drive.
    led_bitmask: u8,
    /// `ring.effect` as written, or stored (no LED ring here).
    ring_effect: u8,
    /// The decks reported attached, a bit each of [`DECK_NAMES`] (none at
    /// boot; [`CrtpVehicle::report_decks`]).
    decks: u8,
    /// The battery voltage the radio chip last reported, V; `None` until
    /// it reports one (no reading is not a full battery).
    vbat_v: Option<f32>,
    pm_state: i8,
    counters: CrtpCounters,
    /// The board's sensors as it started them (`Ok`: the simulator's).
    sensors: Result<(), SensorDown>,
    /// Barometer fixes fused.
    baro_fixes: u32,
    /// The CRCs of the parameter and log tables of contents.
    toc_crcs: TocCrcs,
}

/// The CRCs of the two tables of contents (cflib's cache keys), computed
/// once when the vehicle is made: the tables are fixed, and computed at a
/// client's request the parameters' held the vehicle ≈ 27 000 instructions
/// (the Crazyflie image in QEMU), the longest hold while cflib connects.
#[derive(Debug, Clone, Copy)]
struct TocCrcs {
    /// The parameters' ([`param_entry`]).
    param: u32,
    /// The log variables' ([`LOG_VARS`]).
    log: u32,
}

impl CrtpShared {
    /// The vehicle's shared part with nothing designed yet (motors off
    /// until [`CrtpVehicle::start`] succeeds).
    pub fn unstarted(settings: Settings) -> Self {
        Self {
            lp: Loop::unstarted_with(FcConfig::default(), settings),
            work: WorkState::Idle,
            reply: None,
            persist: None,
            defaults: settings,
            client: ClientCommander::new(),
            log: LogBlocks::new(),
            console: heapless::Deque::new(),
            sampled: heapless::Deque::new(),
            now_us: 0,
            seq: 0,
            u: Vector4::zeros(),
            motors: [0.0; 4],
            heading_seen: false,
            led_bitmask: 0,
            ring_effect: ports::param::RING_EFFECT_DEFAULT,
            decks: 0,
            vbat_v: None,
            pm_state: 0,
            counters: CrtpCounters::default(),
            sensors: Ok(()),
            baro_fixes: 0,
            toc_crcs: TocCrcs {
                param: ports::param::toc_crc(),
                log: ports::logging::toc_crc(),
            },
        }
    }

    /// What the board's sensors did at start-up (a board without sensors
    /// of its own, flying a simulator's, leaves it `Ok`): arming is refused
    /// while one is down, naming it.
    pub fn set_sensors(&mut self, r: Result<(), SensorDown>) {
        self.sensors = r;
    }

    /// The IMU samples that were not good, by kind
    /// ([`fc_loop::supervisor::ImuGuard`]).
    pub fn imu_counters(&self) -> ImuCounters {
        self.client.imu_counters()
    }

    /// A failsafe descent is under way (the IMU went silent in flight).
    pub fn failsafe(&self) -> bool {
        self.client.failsafe()
    }

    /// The board's barometer read `alt_m` (m above sea level: the
    /// BMP388's pressure through [`fc_loop::baro::pressure_altitude_m`]) at
    /// `t_us`: fused as a height fix before the next IMU step, at most at
    /// 50 Hz, its first reading referenced to the estimated height then
    /// ([`Loop::push_baro`]). `true` if it was fused; a reading that is not a
    /// measurement, or one before the estimator has a position, is not.
    pub fn baro(&mut self, t_us: u64, alt_m: f32) -> bool {
        let fused = self.lp.push_baro(t_us, alt_m);
        if fused {
            self.baro_fixes = self.baro_fixes.wrapping_add(1);
        }
        fused
    }

    /// Barometer fixes fused since start-up ([`CrtpShared::baro`]).
    pub fn baro_fixes(&self) -> u32 {
        self.baro_fixes
    }

    /// A parameter write from the board's simulator (our protocol's
    /// `ParamSet` of entry `index` of [`PARAMS`], the same ids as the CRTP
    /// table's first entries), as a client's write is: checked, applied,
    /// re-designing only while the motors are off. Returns the answer, or
    /// `None` when a re-design was queued ([`CrtpShared::take_work`]), whose
    /// answer [`CrtpShared::work_done`] gives.
    pub fn sim_param(&mut self, index: u16, value: f32) -> Option<FromFc> {
        // The parameters CRTP does not serve (the automatic modes') are
        // not this vehicle's.
        let r = match crtp_params().get(usize::from(index)) {
            None => Err(Refusal::Unknown),
            Some(_) => self.param_write(usize::from(index), value, Reply::Sim(index)),
        };
        match r {
            Ok(Written::Later) => None,
            Ok(Written::Now) => Some(fc_loop::param_answer(self.lp.settings(), index, None)),
            Err(e) => Some(fc_loop::param_answer(self.lp.settings(), index, Some(e))),
        }
    }

    /// The controller work a packet asked for, handed to the controller's
    /// side (which answers with [`CrtpShared::work_done`]); until then no
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
                self.client.stop();
                self.say(format_args!("controller reset failed"));
                None
            }
            (ControllerWork::Param { reply, .. }, r) => match reply {
                Reply::Crtp(request) => {
                    if r.is_ok() {
                        self.counters.handled = self.counters.handled.wrapping_add(1);
                    } else {
                        self.counters.refused = self.counters.refused.wrapping_add(1);
                    }
                    self.reply = Some(self.written_reply(request, r.err()));
                    None
                }
                Reply::Sim(index) => Some(fc_loop::param_answer(self.lp.settings(), *index, r.err())),
                Reply::Caller => None,
            },
        }
    }

    /// Controller work is queued or running.
    pub fn busy(&self) -> bool {
        !matches!(self.work, WorkState::Idle)
    }

    /// Armed.
    pub fn armed(&self) -> bool {
        self.client.armed()
    }

    /// The supervisor's gate: the motors turn (armed and flying a
    /// set-point), as a Crazyflie's do. The power stage's `fly` (with the
    /// step's set-point) and the parameters' write rule
    /// ([`fc_loop::Loop::write_param`]).
    pub fn flying(&self) -> bool {
        self.client.flying()
    }

    /// The flight loop (estimator, set-point, counters).
    pub fn flight_loop(&self) -> &Loop {
        &self.lp
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

    /// The motor commands of the last step (the mixer's unit; zero off):
    /// the step's [`Power`].
    pub fn motors(&self) -> [f32; 4] {
        self.motors
    }

    /// The mixer of the parameters in force (`None` until started; the
    /// loop's, [`fc_loop::Loop::mixer`]).
    pub fn mixer(&self) -> Option<&Mixer<f32>> {
        self.lp.mixer()
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

    /// Sends what is waiting: a re-designing write's answer, console lines,
    /// then the log blocks sampled ([`CrtpShared::sample_logs`]).
    pub fn poll<S: CrtpSink>(&mut self, out: &mut S) -> Result<(), S::Error> {
        while self.send_next(out, true)? {}
        Ok(())
    }

    /// Sends the next packet waiting, if any: a re-designing write's
    /// answer, else a console line, else (with `logs`) a log block sampled;
    /// returns whether one was. An image's link takes the vehicle for one
    /// packet at a time ([`Syslink::poll`](crate::syslink::Syslink::poll)):
    /// a backlog drained in one hold (a whole log queue after a re-design,
    /// say) held it for over 15 000 instructions.
    pub fn send_next<S: CrtpSink>(&mut self, out: &mut S, logs: bool) -> Result<bool, S::Error> {
        let next = match self.reply.take() {
            Some(r) => Some(r),
            None => match self.console.pop_front() {
                Some(c) => Some(c),
                None if logs => self.sampled.pop_front(),
                None => None,
            },
        };
        match next {
            Some(p) => out.send(&p).map(|()| true),
            None => Ok(false),
        }
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
        while self.send_next(out, false)? {}
        Ok(())
    }
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
