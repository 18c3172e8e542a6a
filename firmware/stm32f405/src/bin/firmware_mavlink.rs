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
//! what the store held, arming, refusals, and the stack's high-water mark
//! as it grows (checked every 1 000 samples).
//!
//! An RTIC 2 application, its tasks ordered as the other images' are (the
//! sample first, then the vehicle, then the link's housekeeping):
//!
//! | priority | task | interrupt | work |
//! |---|---|---|---|
//! | 3 | `usart1_bytes` | USART1 receive | the link's bytes into their queue (the simulator's `HIL_SENSOR` is the sample's arrival), the vehicle's task pended |
//! | 2 | `vehicle` | CAN2_RX0 (pended) | decodes the queued frames; a `HIL_SENSOR` steps the estimator and the controller and is answered, a ground station's message is handled ([`MavVehicle::handle`]) |
//! | 1 | `housekeeping` | CAN2_RX1 (pended) | the signing timestamp kept on landing, the log |
//!
//! The simulator's samples and the ground station's messages share USART1,
//! so one task decodes both: the sample's estimator and controller steps
//! are one call of the vehicle (the CRTP images split them, their samples
//! coming on a port of their own).
//!
//! [`MavVehicle::handle`]: fc_mavlink::vehicle::MavVehicle::handle
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
fc_stm32f405::board_runtime!();

#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4::stm32f405, peripherals = false)]
mod app {
    use fc_mavlink::params::Settings;
    use fc_mavlink::signing::{Signing, SIMULATOR_UNSIGNED};
    use fc_mavlink::vehicle::{MavSink, MavVehicle, Peer, VehicleCounters};
    use fc_mavlink::{encode_signed, MavCounters, MavHeader, MavMessage, MavReader, MAX_FRAME};
    use fc_stm32f405::board;
    use fc_stm32f405::flash::Kept;
    use fc_storage::Persist;
    use hal_shim::stm32f405::{read_queued, rx_pending, usart_isr, Port, SysTickClock, TxTimeout, Usart};
    use hal_shim::ByteLink;
    use stm32f4::stm32f405::Interrupt;

    /// This vehicle's MAVLink system id (component: MAV_COMP_ID_AUTOPILOT1).
    const SYSTEM_ID: u8 = 1;

    /// Reads of 64 bytes the vehicle's task takes per run; more waiting
    /// pends it again, so the link's task below it is not starved.
    const READS: usize = 16;

    /// Whether the vehicle is armed, as the vehicle's task last saw it:
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
                // Every message fits MAX_FRAME; nothing to send otherwise.
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

    /// The vehicle's task's, locked by the housekeeping task below it only
    /// to read what it logs and to keep a landing's signing timestamp.
    #[shared]
    struct Shared {
        /// The vehicle, in static RAM.
        v: &'static mut MavVehicle,
        /// The link: its transmitter, signing, the store.
        link: Link,
        /// USART1's frames decoded and checked (signatures included).
        reader: MavReader,
    }

    #[local]
    struct Local {
        clock: SysTickClock,
        signing_us: u64,
        tx_errors: u32,
        last: (bool, VehicleCounters, u32, usize),
    }

    #[init]
    fn init(_: init::Context) -> (Shared, Local) {
        fc_stm32f405::stack::paint();
        let (clock, usart) = board::bring_up();
        let Some(v) = the_vehicle() else {
            board::fail("vehicle already taken");
        };
        if v.start().is_err() {
            board::fail("boot parameters refused or design failed");
        }
        defmt::info!(
            "up: MAVLink 2, system {=u8}, waiting on USART1; static RAM {=usize} bytes; tasks: bytes (3), vehicle (2), housekeeping (1)",
            SYSTEM_ID,
            fc_stm32f405::stack::static_ram()
        );
        // The settings kept (this image has no watchdog to widen).
        let mut store =
            fc_stm32f405::flash::open_settings(&ARMED, |_| {}).and_then(|k| cortex_m::singleton!(: Kept = k));
        let mut signing = Signing::new();
        if let Some(st) = store.as_deref_mut() {
            restore(v, st, &mut signing);
        }
        // The simulator's samples share USART1 with the ground station:
        // they pass unsigned (fc_mavlink::signing::SIMULATOR_UNSIGNED).
        signing.also_accept_unsigned(&SIMULATOR_UNSIGNED);
        let signing_us = board::now_us(&clock);
        (
            Shared {
                v,
                link: Link {
                    usart,
                    seq: 0,
                    signing,
                    store,
                },
                reader: MavReader::new(SYSTEM_ID),
            },
            Local {
                clock,
                signing_us,
                tx_errors: 0,
                last: (false, VehicleCounters::default(), 0, 0),
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        loop {
            cortex_m::asm::wfi();
        }
    }

    /// USART1's bytes into their queue; the vehicle's task takes them.
    #[task(binds = USART1, priority = 3)]
    fn usart1_bytes(_: usart1_bytes::Context) {
        usart_isr(Port::Usart1);
        rtic::pend(Interrupt::CAN2_RX0);
    }

    /// The vehicle: the queued frames decoded and handled in order (a
    /// `HIL_SENSOR` is a step, answered), at most [`READS`] reads a run.
    #[task(binds = CAN2_RX0, priority = 2, shared = [v, link, reader], local = [clock, signing_us, tx_errors])]
    fn vehicle(cx: vehicle::Context) {
        let vehicle::LocalResources {
            clock,
            signing_us,
            tx_errors,
            ..
        } = cx.local;
        let now_us = board::now_us(clock);
        // The housekeeping task, below this one, cannot run before it ends.
        (cx.shared.v, cx.shared.link, cx.shared.reader).lock(|v, link, reader| {
            link.signing.advance_us(now_us.saturating_sub(*signing_us));
            *signing_us = now_us;
            let mut buf = [0u8; 64];
            for _ in 0..READS {
                let n = read_queued(Port::Usart1, &mut buf);
                if n == 0 {
                    break;
                }
                for &b in &buf[..n.min(buf.len())] {
                    if let Some(Ok((_, msg))) = reader.push_signed(b, &mut link.signing) {
                        if v.handle(&msg, link, &*clock, now_us).is_err() {
                            *tx_errors = tx_errors.wrapping_add(1);
                            defmt::warn!("USART1 transmit timed out ({=u32} so far)", *tx_errors);
                        }
                    }
                }
            }
            v.set_link_errors(reader.counters().refused());
        });
        if rx_pending() {
            rtic::pend(Interrupt::CAN2_RX0);
        }
        rtic::pend(Interrupt::CAN2_RX1);
    }

    /// The link's housekeeping: on landing the signing timestamp is kept,
    /// so that after a reset the vehicle's signatures go on from there;
    /// then what changed is logged.
    #[task(binds = CAN2_RX1, priority = 1, shared = [v, link, reader], local = [last])]
    fn housekeeping(cx: housekeeping::Context) {
        let (mut v, mut link, mut reader) = (cx.shared.v, cx.shared.link, cx.shared.reader);
        let (armed, counters) = v.lock(|v| (v.armed(), v.counters()));
        let frames = reader.lock(|r| r.counters());
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
        log_changes(armed, &counters, &frames, cx.local.last);
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
                *signing = Signing::with_key(key, ts);
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
        last: &mut (bool, VehicleCounters, u32, usize),
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
        if c.steps / 1000 != last.1.steps / 1000 {
            let hw = fc_stm32f405::stack::high_water();
            if hw > last.3 {
                defmt::info!("stack high-water {=usize} bytes", hw);
                last.3 = hw;
            }
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
