//! The `link hold` row: how long the CRTP images' link task holds the
//! vehicle (`CrtpShared`, under its lock) for the radio packets that take
//! it longest, each handled as the image's lock handles one
//! (`CrtpShared::handle`, a re-design's work then taken and run outside
//! the timing). No interrupt lands in them here, unlike in the images'
//! own figures (`tools/crtp_cflib.py`), where the radio's bytes do.

use super::{hprintln, instructions, CycleClock, SysTickClock};
use fc_crtp::vehicle::{param_named, run_work, CrtpShared, CrtpSink, CrtpVehicle};
use fc_crtp::{Packet, Port};
use fc_loop::params::{Airframe, Settings};
use fc_loop::Exclusive;

/// A sink that drops the answers (the image queues them for the radio).
struct Drop;

impl CrtpSink for Drop {
    type Error = ();
    fn send(&mut self, _: &Packet) -> Result<(), ()> {
        Ok(())
    }
}

/// Parameter id of `group.name` in the CRTP table.
fn id(group: &[u8], name: &[u8]) -> Option<[u8; 2]> {
    Some((param_named(group, name)? as u16).to_le_bytes())
}

/// A packet of `port`/`channel` with the payload `head ++ tail`.
fn packet(port: Port, channel: u8, head: &[u8], tail: &[u8]) -> Option<Packet> {
    let mut p = Packet::new(port, channel, head).ok()?;
    p.extend(tail).ok()?;
    Some(p)
}

/// A high-level commander packet: `command, group` and then `floats`.
fn high_level(command: u8, prefix: &[u8], floats: &[f32], suffix: &[u8]) -> Option<Packet> {
    let mut p = packet(Port::HighLevel, 0, &[command, 0], prefix)?;
    for x in floats {
        p.extend(&x.to_le_bytes()).ok()?;
    }
    p.extend(suffix).ok()?;
    Some(p)
}

/// The packets timed, named: the parameter writes (taken, refused with
/// its console line, re-designing), a set by name of the table's last
/// entry (a lookup that tries every entry), a log block of nine
/// variables, the last parameter's table-of-contents item, arming, a
/// take-off and a go-to.
fn packets() -> Option<[(&'static str, Packet); 9]> {
    let (timeout, mass, w_pos) = (id(b"fs", b"TIMEOUT_MS")?, id(b"veh", b"MASS")?, id(b"mpc", b"W_POS")?);
    let last = fc_crtp::vehicle::PARAM_COUNT as u16 - 1;
    let mut block = [0u8; 29];
    block[..2].copy_from_slice(&[6, 1]);
    for (i, v) in block[2..].chunks_exact_mut(3).enumerate() {
        // Float variables 0 to 8.
        v.copy_from_slice(&[7, i as u8, 0]);
    }
    let by_name = b"\0deck\0bcLedRing\0\x08\0";
    Some([
        ("write taken", packet(Port::Param, 2, &timeout, &80u16.to_le_bytes())?),
        (
            "write refused",
            packet(Port::Param, 2, &mass, &(-1.0f32).to_le_bytes())?,
        ),
        (
            "write re-designing",
            packet(Port::Param, 2, &w_pos, &2.0f32.to_le_bytes())?,
        ),
        ("set by name, last entry", packet(Port::Param, 3, by_name, &[])?),
        ("log block of 9", packet(Port::Log, 1, &block, &[])?),
        ("toc item", packet(Port::Param, 0, &[2], &last.to_le_bytes())?),
        ("arm", packet(Port::Supervisor, 1, &[0x01, 1], &[])?),
        ("take-off", high_level(7, &[], &[1.0, 0.0], &[0, 0, 0, 0x40, 0x40])?),
        ("go-to", high_level(12, &[0, 0], &[1.0, 0.5, -1.0, 0.3, 2.0], &[])?),
    ])
}

/// The vehicle timed (a Crazyflie's settings), in static RAM and designed
/// in place, as the images' is. Made outside the row's stack figure: it
/// is made as the images make theirs at boot, whose stack they report
/// apart (the boot's mark, `fc_stm32f405::stack`).
#[inline(never)]
pub(super) fn vehicle() -> Option<&'static mut CrtpVehicle> {
    let settings = Settings {
        airframe: Airframe::XCrazyflie,
        hub_m: 0.0325,
        ..Settings::os4()
    };
    let v = cortex_m::singleton!(: CrtpVehicle = CrtpVehicle::unstarted(settings))?;
    v.start().ok()?;
    Some(v)
}

/// The longest hold of `v` over [`packets`], each printed; `None` if a
/// packet could not be made. Out of line: its packets are not in the
/// frame of `main`, under every other row's stack figure.
#[inline(never)]
pub(super) fn link_hold_worst(v: &mut CrtpVehicle, clock: &SysTickClock) -> Option<u32> {
    let (shared, ctrl) = v.split();
    let mut worst = 0;
    for (what, p) in packets()? {
        let t0 = clock.now();
        let _ = CrtpShared::handle(shared, &p, &mut Drop);
        let n = instructions(clock.since(t0));
        // A re-design runs after the lock, on the controller.
        if let Some(work) = shared.take_work() {
            let _ = run_work(&mut Exclusive(&mut *shared), ctrl, work);
        }
        hprintln!("budget: link hold, {}: {} instructions", what, n);
        worst = worst.max(n);
    }
    Some(worst)
}
