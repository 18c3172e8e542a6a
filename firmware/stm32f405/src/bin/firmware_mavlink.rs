//! The STM32F405 image speaking MAVLink 2 on USART1 (`thumbv7em-none-eabihf`).
//!
//! The same board and flight loop as `firmware`, behind
//! [`fc_mavlink::vehicle::MavVehicle`]: PX4's simulator interface
//! (`HIL_SENSOR` in, one `HIL_ACTUATOR_CONTROLS` out per sample, in
//! lockstep), a ground station's parameters, arming and set-points, and
//! telemetry — both peers on the one link (the host routes them). It boots
//! with the OS4's parameters; a ground station sets the vehicle's
//! (`sil-host px4-hil --target qemu --vehicle FILE` does). The parameters
//! a ground station sets and the signing key are kept
//! (`fc_stm32f405::flash::open_settings`: a RAM stand-in in QEMU, the
//! flash on a board) and taken again at boot. Logs through defmt: boot,
//! what the store held, arming, refusals, the stack's high-water mark
//! as it grows (checked every 1 000 samples), and what its steps took
//! ([`fc_stm32f405::timing`]: from a `HIL_SENSOR` frame whole to the
//! step's end, every 1 000 steps and at once when one is late).
//!
//! An RTIC 2 application, its tasks ordered as the other images' are (the
//! sample and the estimator first, then the controller, then the link):
//!
//! | priority | task | interrupt | work |
//! |---|---|---|---|
//! | 4 | `usart1_bytes` | USART1 receive | the link's bytes into their queue, the link's task pended |
//! | 3 | `estimator` | CAN2_SCE (pended) | a `HIL_SENSOR` (the sample): the commander's and the estimator's half of its step ([`MavShared::sensor_begin`]), handed to the controller's task |
//! | 2 | `controller` | CAN2_RX0 (pended) | flies the step ([`fly_sensor_step`]), then its end ([`MavShared::sensor_end`]): the motors, the simulator's answer, the modes' events, the telemetry due |
//! | 1 | `link` | CAN2_RX1 (pended) | decodes the queued frames: a `HIL_SENSOR` goes to the estimator's task, a ground station's message is handled ([`MavShared::handle`]); the signing timestamp kept on landing; the log |
//!
//! The simulator's samples and the ground station's messages share
//! USART1, so the link's task decodes both, as PX4's MAVLink receiver
//! does: a sample is handed up to the estimator's task, which preempts the
//! link at once, and the controller's task runs before the next frame is
//! decoded, so the steps and the messages keep the order they came in.
//! The vehicle's state ([`MavShared`]) is locked for the estimator's half,
//! for a step's inputs and result, for the step's end (which writes the
//! step's answer and telemetry to USART1) and for a ground station's
//! message; the controller's step runs with it unlocked. A message that
//! designs the controller (arming, a re-designing parameter) holds the
//! controller meanwhile, so the steps wait for the design, as PX4's HIL
//! lockstep waits for its answer.
//!
//! [`MavShared::sensor_begin`]: fc_mavlink::vehicle::MavShared::sensor_begin
//! [`MavShared::sensor_end`]: fc_mavlink::vehicle::MavShared::sensor_end
//! [`MavShared::handle`]: fc_mavlink::vehicle::MavShared::handle
//! [`MavShared`]: fc_mavlink::vehicle::MavShared
//! [`fly_sensor_step`]: fc_mavlink::vehicle::fly_sensor_step
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
fc_stm32f405::board_runtime!();

#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4::stm32f405, peripherals = false)]
mod app {
    use fc_core::control::AnyController;
    use fc_mavlink::common::HIL_SENSOR_DATA;
    use fc_mavlink::params::Settings;
    use fc_mavlink::signing::{Signing, SIMULATOR_UNSIGNED};
    use fc_mavlink::vehicle::{fly_sensor_step, MavShared, MavSink, MavVehicle, Peer, SensorStep, VehicleCounters};
    use fc_mavlink::{encode_signed, MavCounters, MavHeader, MavMessage, MavReader, MAX_FRAME};
    use fc_stm32f405::board;
    use fc_stm32f405::flash::Kept;
    use fc_stm32f405::timing::{StepTiming, Timing, DEADLINE_TICKS};
    use fc_storage::Persist;
    use hal_shim::stm32f405::{read_queued, rx_waiting, ticks_now, usart_isr, Port, SysTickClock, TxTimeout, Usart};
    use hal_shim::ByteLink;
    use stm32f4::stm32f405::Interrupt;

    /// This vehicle's MAVLink system id (component: MAV_COMP_ID_AUTOPILOT1).
    const SYSTEM_ID: u8 = 1;

    /// Reads of 64 bytes the link's task takes per run; more waiting pends
    /// it again.
    const READS: usize = 16;

    /// USART1 transmits that timed out (the controller's and the link's).
    static TX_ERRORS: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

    /// Whether the vehicle is armed, as the link's task last saw it:
    /// the settings store refuses writes then.
    static ARMED: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

    /// Both peers on USART1, signed once a `SETUP_SIGNING` set a key; the
    /// settings (parameters, the key) kept in `store`.
    pub struct Link {
        usart: Usart,
        seq: u8,
        signing: Signing,
        store: Option<&'static mut Kept>,
    }

    impl MavSink for Link {
        type Error = TxTimeout;
        fn send(&mut self, _to: Peer, msg: &MavMessage) -> Result<(), TxTimeout> {
            let header = MavHeader {
                system_id: u32::from(SYSTEM_ID),
                component_id: 1,
                sequence: self.seq,
            };
            self.seq = self.seq.wrapping_add(1);
            let mut out = [0u8; MAX_FRAME];
            match encode_signed(header, msg, &mut out, &mut self.signing) {
                Ok(n) => self.usart.write_all(&out[..n]),
                // Every message fits MAX_FRAME; held until the owner is heard
                // after a boot on a stored key (MavError::Unclocked).
                Err(_) => Ok(()),
            }
        }
        fn signing(&mut self) -> Option<&mut Signing> {
            Some(&mut self.signing)
        }
        fn storage(&mut self) -> Option<&mut dyn Persist> {
            match &mut self.store {
                Some(s) => Some(&mut **s),
                None => None,
            }
        }
    }

    /// The tasks' resources (see the module's documentation).
    #[shared]
    struct Shared {
        /// The vehicle's state, in static RAM.
        v: &'static mut MavShared,
        /// Its controller, in static RAM.
        ctrl: &'static mut AnyController<f32>,
        /// The link: its transmitter, signing, the store.
        link: Link,
        /// A `HIL_SENSOR` for the estimator's task, with its data-ready:
        /// the SysTick ticks when its frame was whole.
        sample: Option<(HIL_SENSOR_DATA, u64)>,
        /// A step for the controller's task, with its sample's data-ready.
        step: Option<(SensorStep, u64)>,
        /// What every step took ([`fc_stm32f405::timing`]), logged by the
        /// link's task.
        timing: Timing,
    }

    #[local]
    struct Local {
        /// USART1's frames decoded and checked (signatures included).
        reader: MavReader,
        estimator_clock: SysTickClock,
        controller_clock: SysTickClock,
        link_clock: SysTickClock,
        signing_us: u64,
        last: (bool, VehicleCounters, u32, fc_stm32f405::stack::Watch),
        /// The timing figures last logged.
        logged: StepTiming,
    }

    #[init]
    fn init(_: init::Context) -> (Shared, Local) {
        fc_stm32f405::stack::paint();
        let (clock, usart) = board::bring_up();
        let Some(vehicle) = the_vehicle() else {
            board::fail("vehicle already taken");
        };
        if vehicle.start().is_err() {
            board::fail("boot parameters refused or design failed");
        }
        defmt::info!(
            "up: MAVLink 2, system {=u8}, waiting on USART1; static RAM {=usize} bytes; tasks: bytes (4), estimator (3), controller (2), link (1)",
            SYSTEM_ID,
            fc_stm32f405::stack::static_ram()
        );
        // The settings kept (this image has no watchdog to widen).
        let mut store =
            fc_stm32f405::flash::open_settings(&ARMED, |_| {}).and_then(|k| cortex_m::singleton!(: Kept = k));
        let mut signing = Signing::new();
        if let Some(st) = store.as_deref_mut() {
            restore(vehicle, st, &mut signing);
        }
        // The simulator's samples share USART1 with the ground station:
        // they pass unsigned (fc_mavlink::signing::SIMULATOR_UNSIGNED).
        signing.also_accept_unsigned(&SIMULATOR_UNSIGNED);
        let signing_us = board::now_us(&clock);
        let (v, ctrl) = vehicle.split();
        (
            Shared {
                v,
                ctrl,
                link: Link {
                    usart,
                    seq: 0,
                    signing,
                    store,
                },
                sample: None,
                step: None,
                timing: Timing::new(DEADLINE_TICKS),
            },
            Local {
                reader: MavReader::new(SYSTEM_ID),
                estimator_clock: clock,
                controller_clock: clock,
                link_clock: clock,
                signing_us,
                last: (false, VehicleCounters::default(), 0, fc_stm32f405::stack::Watch::new()),
                logged: StepTiming::default(),
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        board::idle()
    }

    /// USART1's bytes into their queue; the link's task takes them.
    #[task(binds = USART1, priority = 4)]
    fn usart1_bytes(_: usart1_bytes::Context) {
        usart_isr(Port::Usart1);
        rtic::pend(Interrupt::CAN2_RX1);
    }

    /// The estimator's half of the sample the link's task handed up; its
    /// step goes to the controller's task.
    #[task(binds = CAN2_SCE, priority = 3, shared = [v, sample, step, timing], local = [estimator_clock])]
    fn estimator(cx: estimator::Context) {
        let clock = &*cx.local.estimator_clock;
        let (mut v, mut sample, mut slot, mut timing) =
            (cx.shared.v, cx.shared.sample, cx.shared.step, cx.shared.timing);
        let Some((m, entry)) = sample.lock(Option::take) else {
            return;
        };
        let now_us = board::now_us(clock);
        if let Some(step) = v.lock(|v| v.sensor_begin(&m, clock, now_us)) {
            timing.lock(|t| t.estimated(entry, ticks_now()));
            if slot.lock(|s| s.replace((step, entry))).is_some() {
                count_dropped("step");
                timing.lock(Timing::job_dropped);
            }
            rtic::pend(Interrupt::CAN2_RX0);
        }
    }

    /// The controller's step, then the step's end: the motors, the
    /// simulator's answer, the modes, the telemetry.
    #[task(binds = CAN2_RX0, priority = 2, shared = [v, ctrl, link, step, timing], local = [controller_clock])]
    fn controller(cx: controller::Context) {
        let clock = &*cx.local.controller_clock;
        let (mut v, mut ctrl, mut link, mut slot, mut timing) = (
            cx.shared.v,
            cx.shared.ctrl,
            cx.shared.link,
            cx.shared.step,
            cx.shared.timing,
        );
        let Some((step, entry)) = slot.lock(Option::take) else {
            return;
        };
        let flown = ctrl.lock(|c| fly_sensor_step(&mut v, c, &step, clock));
        let sent = (&mut v, &mut link).lock(|v, link| v.sensor_end(&step, flown, clock, link));
        // Data-ready to the step's end: the motors, the simulator's answer
        // and the telemetry due written to USART1.
        let done = ticks_now();
        timing.lock(|t| {
            t.flown(entry, done);
            if sent.is_err() {
                t.tx_timeout();
            }
        });
        if sent.is_err() {
            count_tx_error();
        }
    }

    /// The link: the queued frames decoded in order, at most [`READS`]
    /// reads a run (a sample handed to the estimator's task, a ground
    /// station's message handled); then the signing timestamp kept on
    /// landing, so that after a reset the vehicle's signatures go on from
    /// there, and what changed logged.
    #[task(binds = CAN2_RX1, priority = 1, shared = [v, ctrl, link, sample, timing], local = [reader, link_clock, signing_us, last, logged])]
    fn link(cx: link::Context) {
        let link::LocalResources {
            reader,
            link_clock: clock,
            signing_us,
            last,
            logged,
            ..
        } = cx.local;
        let (mut v, mut ctrl, mut link, mut sample, mut timing) = (
            cx.shared.v,
            cx.shared.ctrl,
            cx.shared.link,
            cx.shared.sample,
            cx.shared.timing,
        );
        let now_us = board::now_us(clock);
        link.lock(|l| l.signing.advance_us(now_us.saturating_sub(*signing_us)));
        *signing_us = now_us;
        let mut buf = [0u8; 64];
        for _ in 0..READS {
            let n = read_queued(Port::Usart1, &mut buf);
            if n == 0 {
                break;
            }
            for &b in &buf[..n.min(buf.len())] {
                // Locked a byte at a time: a step the last frame started
                // runs to its end before the next frame is decoded.
                let Some(Ok((_, msg))) = link.lock(|l| reader.push_signed(b, &mut l.signing)) else {
                    continue;
                };
                if let MavMessage::HIL_SENSOR(m) = msg {
                    // Its data-ready: the frame is whole (decoded, checked).
                    if sample.lock(|s| s.replace((m, ticks_now()))).is_some() {
                        count_dropped("sample");
                        timing.lock(Timing::job_dropped);
                    }
                    rtic::pend(Interrupt::CAN2_SCE);
                } else if (&mut v, &mut ctrl, &mut link)
                    .lock(|v, c, link| v.handle(c, &msg, link, &*clock, now_us))
                    .is_err()
                {
                    count_tx_error();
                }
            }
        }
        let frames = reader.counters();
        let (armed, counters) = v.lock(|v| {
            v.set_link_errors(frames.refused());
            (v.armed(), v.counters())
        });
        if rx_waiting(Port::Usart1) {
            rtic::pend(Interrupt::CAN2_RX1);
        }
        if ARMED.swap(armed, core::sync::atomic::Ordering::Relaxed) && !armed {
            link.lock(|link| {
                if let (Some(st), Some(key)) = (link.store.as_deref_mut(), link.signing.key()) {
                    if let Err(e) = st.set_signing(key, link.signing.timestamp()) {
                        defmt::warn!(
                            "storage: the signing timestamp is not kept ({})",
                            defmt::Display2Format(&e)
                        );
                    }
                }
            });
        }
        log_changes(armed, &counters, &frames, last);
        timing.lock(|t| t.snapshot()).log_if_due(logged);
    }

    /// Counts a transmit that timed out, and says so.
    fn count_tx_error() {
        let n = TX_ERRORS.fetch_add(1, core::sync::atomic::Ordering::Relaxed) + 1;
        defmt::warn!("USART1 transmit timed out ({=u32} so far)", n);
    }

    /// Says that a hand-over between the tasks found its slot full (the
    /// task above had not taken the last one: never, as they preempt).
    fn count_dropped(what: &str) {
        defmt::warn!("{=str} dropped: the task above had not taken the last", what);
    }

    /// Takes the settings kept in `st` at boot: the parameters (each
    /// through the write check) and the signing key with its timestamp.
    fn restore(v: &mut MavVehicle, st: &mut Kept, signing: &mut Signing) {
        let (mut taken, mut refused) = (0u16, 0u16);
        for i in 0..fc_mavlink::params::PARAMS.len() {
            if let Ok(Some(value)) = st.param(i as u16) {
                match v.apply(i, value) {
                    Ok(()) => taken += 1,
                    Err(_) => refused += 1,
                }
            }
        }
        let key = match st.signing() {
            Ok(Some((key, ts))) if key != [0; 32] => {
                *signing = Signing::stored(key, ts);
                true
            }
            _ => false,
        };
        defmt::info!(
            "storage: {=u16} stored parameters taken, {=u16} refused; signing key {=str}",
            taken,
            refused,
            if key { "kept: signing on" } else { "none" }
        );
    }

    /// Logs what changed since the last call.
    fn log_changes(
        armed: bool,
        c: &VehicleCounters,
        reader: &MavCounters,
        last: &mut (bool, VehicleCounters, u32, fc_stm32f405::stack::Watch),
    ) {
        if armed != last.0 {
            if armed {
                defmt::info!("armed");
            } else {
                defmt::info!("disarmed");
            }
        }
        if c.params_refused != last.1.params_refused || c.commands_refused != last.1.commands_refused {
            defmt::warn!(
                "refused: {=u32} parameter writes, {=u32} commands",
                c.params_refused,
                c.commands_refused
            );
        }
        if reader.refused() != last.2 {
            defmt::warn!(
                "MAVLink frames refused: crc {=u32} unknown {=u32} unsupported {=u32} signing {=u32} malformed {=u32} other system {=u32}",
                reader.bad_crc,
                reader.unknown,
                reader.unsupported,
                reader.signing,
                reader.malformed,
                reader.other_system
            );
        }
        last.3.poll();
        if c.steps / 1000 != last.1.steps / 1000 {
            last.3.log_if_grown();
        }
        (last.0, last.1, last.2) = (armed, *c, reader.refused());
    }

    /// The vehicle, in static RAM, built unstarted: its controller is
    /// designed in place by `start`, not beneath a stack copy.
    #[inline(never)]
    fn the_vehicle() -> Option<&'static mut MavVehicle> {
        cortex_m::singleton!(: MavVehicle = MavVehicle::unstarted(Settings::os4(), SYSTEM_ID))
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("firmware-mavlink: this binary is the STM32F405 image; build it with --target thumbv7em-none-eabihf");
}
