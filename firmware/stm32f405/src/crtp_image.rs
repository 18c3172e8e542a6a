//! What the CRTP images share (`firmware-crtp` on the plain STM32F405,
//! `firmware-crazyflie` on the Crazyflie 2.1), around the RTIC application
//! both bind ([`crate::crtp_app`]): syslink to the nRF51 radio on USART6,
//! the vehicle ([`fc_crtp::vehicle::CrtpShared`] and its controller, the
//! same code `sil-host crtp` runs in-process) behind it, and the
//! simulator's sensors on USART1.
//!
//! - **USART6, syslink** ([`fc_crtp::syslink`]): `RADIO_READY` at boot, each
//!   radio packet from the nRF51 handled and answered with at most one
//!   downlink packet, battery reports. Under QEMU, `tools/nrf51_bridge.py`
//!   plays the nRF51 between cflib's `udp://` driver and this port.
//! - **USART1, the simulator's sensors**, in our framed protocol as a
//!   simulator feeds `firmware-mavlink` its `HIL_SENSOR`: `ParamSet` (the
//!   simulated vehicle's parameters, answered with `Param`), `Fix` and `Imu`
//!   (each IMU sample answered with the `Actuator` inputs of its step).
//!
//! Logs through defmt: boot, the radio's `RADIO_READY` echo, arming, and
//! link errors on either port as they happen.

use crate::watchdog::{self, FeedRule, Seen};
use core::cell::Cell;
use core::sync::atomic::{AtomicBool, Ordering};
use fc_core::estimate::ImuSample;
use fc_crtp::syslink::SyslinkCounters;
use fc_crtp::vehicle::CrtpShared;
use fc_loop::power::Power;
use fc_loop::supervisor::ImuCounters;
use fc_proto::{encode, FromFc, MAX_FRAME};
use hal_shim::stm32f405::{rx_overruns, Port, TxTimeout, Usart};
use hal_shim::ByteLink;

/// syslink's rate on the Crazyflie 2.1.
pub const SYSLINK_BAUD: u32 = 1_000_000;
/// Downlink packets waiting for an uplink packet (the firmware's
/// `radiolink` queue holds 16).
pub const DOWNLINK: usize = 16;
/// Fixes queued for the next IMU sample.
pub const FIXES: usize = 4;

/// A board's outputs of every step: its motors (none on the plain
/// STM32F405, whose simulator flies the inputs), its LEDs.
pub trait Outputs {
    /// Applies what a step of the vehicle `v` gives the motors, `power`
    /// (its rotor thrusts, zero with the motors off; the motors armed or
    /// not are `v`'s).
    fn drive(&mut self, v: &CrtpShared, power: &Power);
    /// After the step is answered, off its deadline and with the vehicle
    /// unlocked: what the outputs show besides the motors (LEDs) and their
    /// log lines, for a vehicle `armed` whose navigator is in `nav` on a
    /// battery at `battery_v` V.
    fn report(&mut self, armed: bool, nav: fc_loop::nav::NavMode, battery_v: f32);
}

/// A board's watchdog, as the image's tasks report to it (each method is
/// called from the task it names, so the implementation is shared across
/// priorities: `Sync`).
pub trait Watchdog: Sync {
    /// The IMU task finished a sample (data-ready, priority 3).
    fn imu_step(&self);
    /// The controller's task finished a step (priority 2).
    fn controller_step(&self);
    /// The controller's task begins (`true`) or ends a design (tens of
    /// milliseconds without a step: [`fc_crtp::vehicle::ControllerWork::designs`]).
    fn designing(&self, running: bool);
    /// The link's task (the lowest priority), after each batch of steps:
    /// starts the watchdog once both tasks ran, feeds it when both ran again.
    fn service(&self);
}

/// The chip's IWDG under [`crate::watchdog`]'s rule: started once the IMU
/// task and the controller have both run (a board without samples never
/// starts it), fed only when both ran again since the last feed, its
/// timeout widened while the controller's task designs.
pub struct Iwdg {
    rule: FeedRule,
    seen: critical_section::Mutex<Cell<Seen>>,
    started: AtomicBool,
    failed: AtomicBool,
}

impl Iwdg {
    /// Not started: the first [`Watchdog::service`] after both tasks ran
    /// starts it (an image's `static WATCHDOG`).
    pub const fn new() -> Self {
        Self {
            rule: FeedRule::new(),
            seen: critical_section::Mutex::new(Cell::new(Seen::new())),
            started: AtomicBool::new(false),
            failed: AtomicBool::new(false),
        }
    }

    fn registers() -> &'static stm32f4::stm32f405::iwdg::RegisterBlock {
        // SAFETY: the IWDG's fixed address; only this type writes it.
        unsafe { &*stm32f4::stm32f405::IWDG::ptr() }
    }

    fn refused(&self, e: watchdog::WatchdogError) {
        if !self.failed.swap(true, Ordering::Relaxed) {
            defmt::error!("IWDG: {}", defmt::Display2Format(&e));
        }
    }
}

impl Watchdog for Iwdg {
    fn imu_step(&self) {
        self.rule.imu_step();
    }

    fn controller_step(&self) {
        self.rule.controller_step();
    }

    fn designing(&self, running: bool) {
        if !self.started.load(Ordering::Relaxed) {
            return;
        }
        let r = if running {
            watchdog::set_timeout(
                Self::registers(),
                watchdog::DESIGN_PRESCALER_BITS,
                watchdog::DESIGN_RELOAD,
            )
        } else {
            watchdog::set_timeout(Self::registers(), watchdog::PRESCALER_BITS, watchdog::RELOAD)
        };
        if let Err(e) = r {
            self.refused(e);
        }
    }

    fn service(&self) {
        let may = critical_section::with(|cs| {
            let cell = self.seen.borrow(cs);
            let mut seen = cell.get();
            let may = self.rule.may_feed(&mut seen);
            cell.set(seen);
            may
        });
        if !may {
            return;
        }
        if self.started.load(Ordering::Relaxed) {
            watchdog::feed(Self::registers());
        } else if !self.failed.load(Ordering::Relaxed) {
            match watchdog::start(Self::registers()) {
                Ok(()) => {
                    self.started.store(true, Ordering::Relaxed);
                    defmt::info!(
                        "IWDG started: {=u32} µs, fed while the IMU task and the controller both run",
                        watchdog::timeout_us(watchdog::LSI_HZ)
                    );
                }
                Err(e) => self.refused(e),
            }
        }
    }
}

impl Default for Iwdg {
    fn default() -> Self {
        Self::new()
    }
}

/// A board's own IMU, read on its bus's interrupts (the Crazyflie 2.1's
/// BMI088 on I2C3, its data-ready on EXTI14). Its samples go through the
/// same task as the simulator's: `data_ready`, which each finished sample
/// pends. A board without one (QEMU models no I2C and no GPIO; the plain
/// STM32F405 flies the simulator's) is [`SimulatorOnly`].
pub trait ImuBus: Send {
    /// The data-ready line fired at `entry` (SysTick ticks): starts the
    /// sample's reads. `true` when a sample is ready for `data_ready` (the
    /// last one, abandoned: missing).
    fn data_ready(&mut self, entry: u64) -> bool;
    /// The bus's event (`error` false) or error interrupt: `true` when a
    /// sample is ready.
    fn bus_interrupt(&mut self, error: bool) -> bool;
    /// The sample ready, if any: its data-ready time (SysTick ticks) and the
    /// sample in body FRD, or `None` (the read failed; counted missing).
    fn take(&mut self) -> Option<(u64, Option<ImuSample>)>;
    /// The board's barometer reading since the last call, if any: the
    /// data-ready time of the IMU sample it was read after (SysTick ticks)
    /// and its pressure altitude, m above sea level
    /// ([`fc_loop::baro::pressure_altitude_m`]). None on a board without one.
    fn take_baro(&mut self) -> Option<(u64, f32)> {
        None
    }
}

/// No IMU of the board's own: every sample is the simulator's, on USART1.
pub struct SimulatorOnly;

impl SimulatorOnly {
    /// The bus and the sensors' start-up result: none to start, the
    /// simulator's taken as up.
    pub fn started() -> (Self, Result<(), fc_loop::supervisor::SensorDown>) {
        (SimulatorOnly, Ok(()))
    }
}

impl ImuBus for SimulatorOnly {
    fn data_ready(&mut self, _: u64) -> bool {
        false
    }
    fn bus_interrupt(&mut self, _: bool) -> bool {
        false
    }
    fn take(&mut self) -> Option<(u64, Option<ImuSample>)> {
        None
    }
}

/// What the simulator's link did.
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct SimCounters {
    /// Frames that did not decode.
    pub bad: u32,
    /// Fixes dropped: more than [`FIXES`] before one IMU sample.
    pub fixes_dropped: u32,
    /// Frames of kinds this image does not take from the simulator.
    pub ignored: u32,
}

/// Sends `m` to the simulator.
pub fn send(usart: &mut Usart, m: &FromFc) -> Result<(), TxTimeout> {
    let mut out = [0u8; MAX_FRAME];
    match encode(m, &mut out) {
        Ok(n) => usart.write_all(&out[..n]),
        // Every answer fits MAX_FRAME; nothing to send otherwise.
        Err(_) => Ok(()),
    }
}

/// Logs what changed since the last call: arming, the radio's and the
/// simulator's link errors, and the IMU's bad samples (a silence past
/// 10 ms at once; the rest once they stop changing, so a dead part logs a
/// line per episode, not per sample).
pub fn log_changes(armed: bool, imu: ImuCounters, radio: &SyslinkCounters, sim: &SimCounters, last: &mut Last) {
    if imu.timeouts != last.imu.timeouts {
        defmt::error!(
            "IMU silent for more than 10 ms: failsafe descent ({=u32} so far)",
            imu.timeouts
        );
    }
    if imu == last.imu && imu != last.imu_logged {
        defmt::warn!(
            "IMU: {=u32} samples missing, {=u32} bad (not finite, out of range), {=u32} steps flown on the last good one, {=u32} silences past 10 ms",
            imu.missing,
            imu.bad,
            imu.held,
            imu.timeouts
        );
        last.imu_logged = imu;
    }
    if radio.ready != last.radio.ready {
        defmt::info!("nRF51 radio ready (RADIO_READY echoed)");
    }
    if armed != last.armed {
        if armed {
            defmt::info!("armed");
        } else {
            defmt::info!("disarmed");
        }
    }
    if radio.bad_frames != last.radio.bad_frames || radio.downlink_dropped != last.radio.downlink_dropped {
        defmt::warn!(
            "syslink: {=u32} frames dropped (length, checksum), {=u32} downlink packets dropped (queue full), {=u32} bytes overrun",
            radio.bad_frames,
            radio.downlink_dropped,
            rx_overruns(Port::Usart6)
        );
    }
    if *sim != last.sim {
        defmt::warn!(
            "simulator link: {=u32} bad frames, {=u32} fixes dropped, {=u32} frames ignored, {=u32} bytes overrun",
            sim.bad,
            sim.fixes_dropped,
            sim.ignored,
            rx_overruns(Port::Usart1)
        );
    }
    last.armed = armed;
    last.imu = imu;
    last.radio = *radio;
    last.sim = *sim;
}

/// What [`log_changes`] saw last.
#[derive(Default)]
pub struct Last {
    armed: bool,
    imu: ImuCounters,
    imu_logged: ImuCounters,
    radio: SyslinkCounters,
    sim: SimCounters,
}
