//! The CRTP image's loop, shared by every board that is a Crazyflie's STM32
//! (`firmware-crtp` on the plain STM32F405, `firmware-crazyflie` on the
//! Crazyflie 2.1): syslink to the nRF51 radio on USART6, the vehicle
//! ([`fc_crtp::vehicle::CrtpVehicle`], the same code `sil-host crtp` runs
//! in-process) behind it, and the simulator's sensors on USART1.
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

use crate::PCLK2_HZ;
use fc_core::estimate::{Fix, ImuSample};
use fc_crtp::syslink::{Syslink, SyslinkCounters};
use fc_crtp::vehicle::CrtpVehicle;
use fc_loop::{fix_from_wire, param_answer};
use fc_proto::{encode, FrameDecoder, FromFc, ToFc, MAX_FRAME};
use hal_shim::stm32f405::{rx_overruns, Port, SysTickClock, TxTimeout, Usart};
use hal_shim::ByteLink;
use nalgebra::{Vector3, Vector4};

/// syslink's rate on the Crazyflie 2.1.
const SYSLINK_BAUD: u32 = 1_000_000;
/// Downlink packets waiting for an uplink packet (the firmware's
/// `radiolink` queue holds 16).
const DOWNLINK: usize = 16;
/// Fixes queued for the next IMU sample.
const FIXES: usize = 4;

/// What the simulator's link did.
#[derive(Clone, Copy, PartialEq, Eq, Default)]
struct SimCounters {
    /// Frames that did not decode.
    bad: u32,
    /// Fixes dropped: more than [`FIXES`] before one IMU sample.
    fixes_dropped: u32,
    /// Frames of kinds this image does not take from the simulator.
    ignored: u32,
}

/// Sends `m` to the simulator.
fn send(usart: &mut Usart, m: &FromFc) -> Result<(), TxTimeout> {
    let mut out = [0u8; MAX_FRAME];
    match encode(m, &mut out) {
        Ok(n) => usart.write_all(&out[..n]),
        // Every answer fits MAX_FRAME; nothing to send otherwise.
        Err(_) => Ok(()),
    }
}

/// One frame from the simulator.
fn on_sim_frame(
    m: ToFc,
    v: &mut CrtpVehicle,
    fixes: &mut heapless::Vec<Fix, FIXES>,
    sim: &mut Usart,
    clock: &SysTickClock,
    c: &mut SimCounters,
    on_output: &mut dyn FnMut(&CrtpVehicle, &Vector4<f32>),
) -> Result<(), TxTimeout> {
    match m {
        ToFc::ParamSet { index, value } => {
            let refusal = v.write_param(usize::from(index), value).err();
            send(sim, &param_answer(v.core().settings(), index, refusal))
        }
        ToFc::Fix(w) => {
            if fixes.push(fix_from_wire(&w)).is_err() {
                c.fixes_dropped = c.fixes_dropped.wrapping_add(1);
            }
            Ok(())
        }
        ToFc::Imu { seq, t_us, gyro, accel } => {
            let imu = ImuSample {
                gyro_frd_radps: Vector3::from(gyro),
                accel_frd_mps2: Vector3::from(accel),
            };
            let u = v.imu_step(t_us, &imu, fixes, clock);
            fixes.clear();
            on_output(v, &u);
            send(
                sim,
                &FromFc::Actuator {
                    seq,
                    u: [u[0], u[1], u[2], u[3]],
                    failsafe: false,
                },
            )
        }
        _ => {
            c.ignored = c.ignored.wrapping_add(1);
            Ok(())
        }
    }
}

/// Logs what changed since the last call.
fn log_changes(v: &CrtpVehicle, radio: &SyslinkCounters, sim: &SimCounters, last: &mut Last) {
    if radio.ready != last.radio.ready {
        defmt::info!("nRF51 radio ready (RADIO_READY echoed)");
    }
    if v.armed() != last.armed {
        if v.armed() {
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
    *last = Last {
        armed: v.armed(),
        radio: *radio,
        sim: *sim,
    };
}

/// What [`log_changes`] saw last.
#[derive(Default)]
struct Last {
    armed: bool,
    radio: SyslinkCounters,
    sim: SimCounters,
}

/// Runs the CRTP image on `v` (started), the simulator on `sim` (USART1)
/// and the radio on USART6, never returning. `idle` waits for the next
/// interrupt (the board's); `on_output` is given the vehicle and every IMU
/// step's inputs `[U1 N, U2 N, U3 N, U4 N·m]`, for the board's motors.
pub fn run(
    v: &'static mut CrtpVehicle,
    mut sim: Usart,
    clock: SysTickClock,
    idle: fn(),
    on_output: &mut dyn FnMut(&CrtpVehicle, &Vector4<f32>),
) -> ! {
    let mut radio = Usart::init(Port::Usart6, PCLK2_HZ, SYSLINK_BAUD);
    let mut syslink: Syslink<DOWNLINK> = Syslink::new();
    if syslink.boot(&mut radio).is_err() {
        defmt::warn!("USART6 transmit timed out (RADIO_READY)");
    }
    defmt::info!("up: CRTP over syslink on USART6, the simulator on USART1");
    let mut decoder: FrameDecoder = FrameDecoder::new();
    let mut fixes: heapless::Vec<Fix, FIXES> = heapless::Vec::new();
    let mut sc = SimCounters::default();
    let mut last = Last::default();
    let mut tx_errors: u32 = 0;
    let mut buf = [0u8; 64];
    loop {
        let mut ok = true;
        // The simulator's frames first: a sample waits for its answer.
        while let Ok(n @ 1..) = sim.read(&mut buf) {
            for &b in &buf[..n] {
                match decoder.push::<ToFc>(b) {
                    None => {}
                    Some(Err(_)) => sc.bad = sc.bad.wrapping_add(1),
                    Some(Ok(m)) => ok &= on_sim_frame(m, v, &mut fixes, &mut sim, &clock, &mut sc, on_output).is_ok(),
                }
            }
            // Log blocks that fell due, queued for the next uplink packet.
            syslink.poll(v);
        }
        while let Ok(n @ 1..) = radio.read(&mut buf) {
            ok &= syslink.receive(&buf[..n], v, &mut radio).is_ok();
        }
        if !ok {
            tx_errors = tx_errors.wrapping_add(1);
            defmt::warn!("a USART transmit timed out ({=u32} so far)", tx_errors);
        }
        log_changes(v, &syslink.counters(), &sc, &mut last);
        idle();
    }
}
