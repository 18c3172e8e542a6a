//! Packets, TOCs, log blocks and a vehicle session, against the formats
//! cflib 0.1.34 parses and the Crazyflie firmware sends; and 10⁶ random and
//! mutated packets.

use crate::log::{self, LogBlocks};
use crate::toc::{self, Name};
use crate::vehicle::{param_entry, CrtpSink, CrtpVehicle, LOG_VARS, PARAM_COUNT};
use crate::{CrtpError, Packet, Port};
use fc_core::estimate::{Fix, ImuSample};
use fc_loop::params::Settings;
use hal_shim::host::MonotonicClock;
use nalgebra::Vector3;

/// Keeps what the vehicle sends.
#[derive(Default)]
struct Sent(Vec<Packet>);

impl CrtpSink for Sent {
    type Error = core::convert::Infallible;
    fn send(&mut self, p: &Packet) -> Result<(), Self::Error> {
        self.0.push(*p);
        Ok(())
    }
}

fn pk(port: Port, ch: u8, payload: &[u8]) -> Packet {
    Packet::new(port, ch, payload).unwrap()
}

/// The answer to `p` (the last packet sent on `p`'s port).
fn ask(v: &mut CrtpVehicle, p: Packet) -> Packet {
    let mut out = Sent::default();
    v.handle(&p, &mut out).unwrap();
    *out.0.iter().rev().find(|a| a.port() == p.port()).expect("an answer")
}

#[test]
fn headers_are_read_as_cflib_writes_them() {
    // cflib sets bits 2–3 of the header; they are ignored.
    let p = Packet::from_bytes(&[0x5D, 1, 2]).unwrap();
    assert_eq!((p.port(), p.channel(), p.payload()), (5, 1, &[1u8, 2][..]));
    assert!(Packet::from_bytes(&[0xFF]).unwrap().is_null());
    assert_eq!(Packet::from_bytes(&[]), Err(CrtpError::Empty));
    assert_eq!(Packet::from_bytes(&[0; 32]), Err(CrtpError::TooLong(31)));
    let mut b = [0u8; crate::MAX_PACKET];
    let n = pk(Port::Param, 2, &[1, 2, 3]).write_to(&mut b);
    assert_eq!(&b[..n], &[0x22, 1, 2, 3]);
}

#[test]
fn every_toc_entry_fits_one_packet_and_the_crc_follows_the_table() {
    for (i, v) in LOG_VARS.iter().enumerate() {
        let n = Name {
            group: v.group,
            name: v.name,
            lower_group: false,
        };
        toc::item_packet(Port::Log, i as u16, v.kind, &n).expect("log name fits");
    }
    for i in 0..PARAM_COUNT {
        let (n, t, _) = param_entry(i).unwrap();
        let p = toc::item_packet(Port::Param, i as u16, t, &n).expect("param name fits");
        // cflib: group and name split at the zeros after the type byte.
        let text = &p.payload()[4..];
        assert_eq!(text.iter().filter(|&&b| b == 0).count(), 2, "{p:?}");
    }
    assert_eq!(param_entry(PARAM_COUNT), None);
    // The log's table with entry 3's type set to `t`.
    let crc_with = |t: u8| {
        toc::crc_of_items(LOG_VARS.len() as u16, |id| {
            let v = &LOG_VARS[usize::from(id)];
            let n = Name {
                group: v.group,
                name: v.name,
                lower_group: false,
            };
            toc::item_packet(Port::Log, id, if id == 3 { t } else { v.kind }, &n).unwrap()
        })
    };
    assert_ne!(crc_with(log::types::FLOAT), crc_with(log::types::FP16));
}

/// CRC-32 (IEEE 802.3, zlib's `crc32`), bit by bit: the test's own
/// oracle, apart from the `crc` crate the vehicle uses.
fn crc32_bitwise(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    !c
}

/// Each table of contents' `GET_INFO_V2` CRC (cflib's cache key, computed
/// once when the vehicle is made) is the CRC-32 of the table as
/// `GET_ITEM_V2` serves it, entry by entry: type byte, `group\0name\0`.
#[test]
fn toc_info_crcs_are_the_crc_of_the_served_tables() {
    assert_eq!(crc32_bitwise(b"123456789"), 0xCBF4_3926, "the oracle's check value");
    let mut v = at_rest(0);
    for port in [Port::Param, Port::Log] {
        let info = ask(&mut v, pk(port, 0, &[toc::CMD_GET_INFO_V2]));
        let d = info.payload();
        let count = u16::from_le_bytes([d[1], d[2]]);
        let crc = u32::from_le_bytes([d[3], d[4], d[5], d[6]]);
        let mut table = Vec::new();
        for id in 0..count {
            let [lo, hi] = id.to_le_bytes();
            let item = ask(&mut v, pk(port, 0, &[toc::CMD_GET_ITEM_V2, lo, hi]));
            assert_eq!(&item.payload()[..3], &[toc::CMD_GET_ITEM_V2, lo, hi], "{port:?} {id}");
            table.extend_from_slice(&item.payload()[3..]);
        }
        assert!(table.len() > usize::from(count) * 4, "{port:?}: {} B", table.len());
        assert_eq!(crc, crc32_bitwise(&table), "{port:?}");
    }
}

#[test]
fn log_blocks_answer_every_error_cflib_knows() {
    let mut b = LogBlocks::new();
    let float = |id: u16| [log::types::FLOAT, id as u8, (id >> 8) as u8];
    assert_eq!(b.create(1, &float(0), 28), 0);
    assert_eq!(b.create(1, &float(0), 28), log::EEXIST);
    assert_eq!(b.append(9, &float(0), 28), log::ENOENT);
    assert_eq!(b.append(1, &float(28), 28), log::ENOENT, "an id past the TOC");
    assert_eq!(b.append(1, &[0x0F, 0, 0], 28), log::ENOEXEC, "no such type");
    // 26 bytes of values: six more floats fit (7 · 4 = 28 > 26 does not).
    let six: Vec<u8> = (0..5).flat_map(|_| float(1)).collect();
    assert_eq!(b.append(1, &six, 28), 0);
    assert_eq!(b.append(1, &float(2), 28), log::E2BIG);
    for id in 2..=16 {
        assert_eq!(b.create(id, &[], 28), 0);
    }
    assert_eq!(b.create(17, &[], 28), log::ENOMEM, "a 17th block");
    assert_eq!(b.start(1, 10, 5_000), 0);
    let p = b.next_due(5_000, |v| v as f32 + 0.5).unwrap();
    assert_eq!(p.header() & 0xF3, 0x52);
    // Block id, 24-bit ms timestamp (5), then the values.
    assert_eq!(&p.payload()[..4], &[1, 5, 0, 0]);
    assert_eq!(&p.payload()[4..8], &0.5f32.to_le_bytes());
    assert!(b.next_due(14_999, |_| 0.0).is_none() && b.next_due(15_000, |_| 0.0).is_some());
    assert_eq!(b.stop(1), 0);
    assert!(b.next_due(99_000, |_| 0.0).is_none());
    assert_eq!(b.delete(1), 0);
    assert_eq!(b.delete(1), log::ENOENT);
    // 128 variables in all: the 129th is refused.
    let mut c = LogBlocks::new();
    let u8s: Vec<u8> = (0..26).flat_map(|_| [log::types::U8, 0, 0]).collect();
    for id in 0..4 {
        assert_eq!(c.create(id, &u8s, 28), 0);
    }
    assert_eq!(c.create(4, &u8s[..24 * 3], 28), 0);
    assert_eq!(c.create(5, &[log::types::U8, 0, 0], 28), log::ENOMEM);
}

#[test]
fn values_are_sent_as_the_type_asked_for() {
    let mut b = [0u8; 4];
    assert_eq!(log::encode(3.7, log::types::FP16, &mut b), Some(2));
    assert_eq!(
        half::f16::from_le_bytes([b[0], b[1]]).to_f32(),
        half::f16::from_f32(3.7).to_f32()
    );
    assert_eq!(log::encode(300.0, log::types::U8, &mut b), Some(1));
    assert_eq!(b[0], 255, "saturated");
    assert_eq!(log::encode(-2.9, log::types::I16, &mut b), Some(2));
    assert_eq!(i16::from_le_bytes([b[0], b[1]]), -2);
    assert_eq!(log::encode(1.0, 0, &mut b), None);
}

/// A vehicle at rest on the ground, aligned on a mocap fix (position and
/// heading) for `ms` ms.
/// A vehicle at rest for `ms`, its radio chip's battery report (3.9 V) in.
fn at_rest(ms: u64) -> CrtpVehicle {
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    v.set_battery(3.9, 0);
    rest(&mut v, 0, ms);
    v
}

/// A vehicle whose radio chip has not reported the battery yet does not
/// arm on a voltage it never measured, and says why; the first report lets it.
#[test]
fn no_battery_reading_no_arming() {
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    rest(&mut v, 0, 3000);
    assert!(!v.battery_reported());
    assert_eq!(v.battery_v(), 0.0, "no reading is not a full battery");
    let arm = pk(Port::Supervisor, 1, &[0x01, 1]);
    let (a, said) = ask_said(&mut v, arm);
    assert_eq!(a.payload(), &[0x81, 0, 0]);
    assert!(said.contains("arming refused: no battery reading yet"), "{said}");
    v.set_battery(f32::NAN, 0);
    assert!(!v.battery_reported(), "a NaN is no reading");
    v.set_battery(3.9, 0);
    assert!(v.battery_reported());
    assert_eq!(ask(&mut v, arm).payload(), &[0x81, 1, 1]);
}

fn rest(v: &mut CrtpVehicle, from_ms: u64, ms: u64) {
    let clock = MonotonicClock::default();
    let imu = ImuSample {
        gyro_frd_radps: Vector3::zeros(),
        accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
    };
    let mut fix = Fix::EMPTY;
    fix.pos_ned_m = Some(Vector3::zeros());
    fix.pos_sigma_m = Vector3::repeat(0.005);
    fix.yaw_rad = Some(0.0);
    fix.yaw_sigma_rad = 0.02;
    for k in from_ms..from_ms + ms {
        let fixes = if k % 10 == 0 { &[fix][..] } else { &[] };
        v.imu_step((k + 1) * 1000, &imu, fixes, &clock);
    }
}

#[test]
fn a_session_answers_as_a_crazyflie() {
    let mut v = at_rest(0);
    let src = ask(&mut v, pk(Port::Link, 1, &[0]));
    assert_eq!(&src.payload()[..18], b"Bitcraze Crazyflie");
    let echo = pk(Port::Link, 0, b"ping");
    assert_eq!(ask(&mut v, echo), echo);
    let ver = ask(&mut v, pk(Port::Platform, 1, &[0]));
    assert_eq!(ver.payload(), &[0, 12, 0, 0, 0]);
    let mem = ask(&mut v, pk(Port::Mem, 0, &[1]));
    assert_eq!(mem.payload(), &[1, 1], "one memory: the trajectories'");
    // Param TOC info: count and CRC.
    let info = ask(&mut v, pk(Port::Param, 0, &[toc::CMD_GET_INFO_V2]));
    assert_eq!(
        u16::from_le_bytes([info.payload()[1], info.payload()[2]]) as usize,
        PARAM_COUNT
    );
    // Read VEH_MASS (id 0): [id, status 0, f32].
    let r = ask(&mut v, pk(Port::Param, 1, &[0, 0]));
    assert_eq!(&r.payload()[..3], &[0, 0, 0]);
    assert_eq!(crate::f32_at(r.payload(), 3), Some(Settings::os4().vehicle.mass_kg));
    // A write out of range is answered with the value in force.
    let mut w = vec![0u8, 0];
    w.extend_from_slice(&(-1.0f32).to_le_bytes());
    let r = ask(&mut v, pk(Port::Param, 2, &w));
    assert_eq!(crate::f32_at(r.payload(), 2), Some(Settings::os4().vehicle.mass_kg));
    // Unknown id: ENOENT.
    let r = ask(&mut v, pk(Port::Param, 1, &[0xFF, 0x7F]));
    assert_eq!(r.payload(), &[0xFF, 0x7F, log::ENOENT]);
}

/// The high-level commander's `TAKEOFF_2` to `height_m` over `dur_s`
/// (group 0, yaw 0, not the current yaw).
fn takeoff(height_m: f32, dur_s: f32) -> Packet {
    let mut d = vec![7u8, 0];
    for x in [height_m, 0.0] {
        d.extend_from_slice(&x.to_le_bytes());
    }
    d.push(0);
    d.extend_from_slice(&dur_s.to_le_bytes());
    pk(Port::HighLevel, 0, &d)
}

#[test]
fn arming_waits_for_the_estimator_and_takeoff_for_arming() {
    let mut v = at_rest(5);
    let no = ask(&mut v, pk(Port::Supervisor, 1, &[0x01, 1]));
    assert_eq!(no.payload(), &[0x81, 0, 0], "refused while aligning");
    let takeoff = takeoff(0.5, 2.0);
    let mut out = Sent::default();
    v.handle(&takeoff, &mut out).unwrap();
    assert!(!v.flying() && v.counters().refused == 1, "not armed: refused");
    assert_eq!(console_of(&out.0), "not armed\n", "the take-off's refusal is said");
    // A streamed set-point while disarmed is refused too, and not said: a
    // client streams at 100 Hz.
    let mut hold = vec![7u8];
    for x in [0.0f32, 0.0, 0.5, 0.0] {
        hold.extend_from_slice(&x.to_le_bytes());
    }
    let mut quiet = Sent::default();
    v.handle(&pk(Port::Generic, 0, &hold), &mut quiet).unwrap();
    assert!(!v.flying() && v.counters().refused == 2);
    assert_eq!(console_of(&quiet.0), "");
    rest(&mut v, 5, 3000);
    let yes = ask(&mut v, pk(Port::Supervisor, 1, &[0x01, 1]));
    assert_eq!(yes.payload(), &[0x81, 1, 1]);
    let bits = ask(&mut v, pk(Port::Supervisor, 0, &[0x0C]));
    let bits = u16::from_le_bytes([bits.payload()[1], bits.payload()[2]]);
    assert_eq!(bits & 0b1010, 0b1010, "armed, can fly: {bits:#x}");
    v.handle(&takeoff, &mut out).unwrap();
    assert!(v.flying());
    // A NaN set-point is refused; the flight goes on.
    let mut nan = vec![7u8];
    for x in [f32::NAN, 0.0, 0.5, 0.0] {
        nan.extend_from_slice(&x.to_le_bytes());
    }
    v.handle(&pk(Port::Generic, 0, &nan), &mut out).unwrap();
    assert_eq!(v.counters().bad_value, 1);
    assert!(v.flying());
    // Thrust 0 on the legacy commander (cflib's goodbye) stops the motors.
    let mut rpyt = vec![0u8; 12];
    rpyt.extend_from_slice(&0u16.to_le_bytes());
    v.handle(&pk(Port::Commander, 0, &rpyt), &mut out).unwrap();
    assert!(!v.flying() && v.armed());
}

/// cflib's memory write of `data` at `addr` of memory `id` (channel 2).
fn mem_write(id: u8, addr: u32, data: &[u8]) -> Packet {
    let mut d = vec![id];
    d.extend_from_slice(&addr.to_le_bytes());
    d.extend_from_slice(data);
    pk(Port::Mem, 2, &d)
}

/// A trajectory as cflib's `autonomous_sequence_high_level.py` flies one:
/// the memory listed as cflib's `TYPE_TRAJ` of 4096 bytes, a `Poly4D`
/// piece written in cflib's 24-byte chunks and read back, defined, and
/// started relative to where the take-off left the vehicle; the flight
/// follows the piece (in NED), and while it flies the memory refuses
/// writes (status `EBUSY`, said). Bad definitions are refused by name.
#[test]
fn a_trajectory_is_uploaded_defined_and_flown_as_cflib_does() {
    let mut v = at_rest(3000);
    let details = ask(&mut v, pk(Port::Mem, 0, &[2, 0]));
    let mut want = vec![2u8, 0, 0x12];
    want.extend_from_slice(&4096u32.to_le_bytes());
    want.extend_from_slice(&[0; 8]);
    assert_eq!(details.payload(), &want[..]);
    assert_eq!(ask(&mut v, pk(Port::Mem, 0, &[2, 1])).payload(), &[2, 1], "no memory 1");
    // One piece as cflib's Poly4D.pack writes it: x = 2 + 0.5 t, y = 0,
    // z = 0 (the Crazyflie's frame), yaw 0, over 3 s.
    let mut piece = Vec::new();
    for c in [[2.0f32, 0.5], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]] {
        let mut poly = [0.0f32; 8];
        poly[..2].copy_from_slice(&c);
        piece.extend(poly.iter().flat_map(|x| x.to_le_bytes()));
    }
    piece.extend(3.0f32.to_le_bytes());
    for (i, chunk) in piece.chunks(24).enumerate() {
        let addr = (i * 24) as u32;
        let a = ask(&mut v, mem_write(0, addr, chunk));
        let mut ok = vec![0u8];
        ok.extend_from_slice(&addr.to_le_bytes());
        ok.push(0);
        assert_eq!(a.payload(), &ok[..], "chunk {i}");
    }
    let mut read = vec![0u8];
    read.extend_from_slice(&24u32.to_le_bytes());
    read.push(24);
    let back = ask(&mut v, pk(Port::Mem, 1, &read));
    assert_eq!(&back.payload()[..6], &[0, 24, 0, 0, 0, 0]);
    assert_eq!(&back.payload()[6..], &piece[24..48]);
    let past = ask(&mut v, mem_write(0, 4090, &[0; 8]));
    assert_eq!(past.payload()[5], 5, "past the end: EIO");
    // DEFINE_TRAJECTORY: id 1, in memory, poly4d, offset 0, 1 piece.
    let define = |kind: u8, pieces: u8| {
        let mut d = vec![6u8, 1, 1, kind];
        d.extend_from_slice(&0u32.to_le_bytes());
        d.push(pieces);
        pk(Port::HighLevel, 0, &d)
    };
    let tell = |v: &mut CrtpVehicle, p: Packet| {
        let mut out = Sent::default();
        v.handle(&p, &mut out).unwrap();
        console_of(&out.0) + &console(v)
    };
    let said = tell(&mut v, define(1, 1));
    assert!(
        said.contains("HL trajectory 1 refused: only uncompressed poly4d"),
        "{said}"
    );
    let said = tell(&mut v, define(0, 32));
    assert!(said.contains("past the trajectory memory's 4096 bytes"), "{said}");
    let mut out = Sent::default();
    v.handle(&define(0, 1), &mut out).unwrap();
    assert_eq!(console_of(&out.0), "");
    // Armed, take off to 1 m, then START_TRAJECTORY_2: relative, id 1.
    assert_eq!(
        ask(&mut v, pk(Port::Supervisor, 1, &[0x01, 1])).payload(),
        &[0x81, 1, 1]
    );
    v.handle(&takeoff(1.0, 2.0), &mut out).unwrap();
    rest(&mut v, 3000, 2500);
    let mut start = vec![13u8, 0, 1, 0, 0, 1];
    start.extend_from_slice(&1.0f32.to_le_bytes());
    v.handle(&pk(Port::HighLevel, 0, &start), &mut out).unwrap();
    assert_eq!(console_of(&out.0), "");
    rest(&mut v, 5500, 1000);
    let sp = v.flight_loop().setpoint();
    assert!(
        (sp.pos_ned_m - Vector3::new(0.5, 0.0, -1.0)).norm() < 0.01,
        "{:?}",
        sp.pos_ned_m
    );
    assert!(
        (sp.vel_ned_mps - Vector3::new(0.5, 0.0, 0.0)).norm() < 1e-4,
        "{:?}",
        sp.vel_ned_mps
    );
    let (a, said) = ask_said(&mut v, mem_write(0, 0, &[0xff; 24]));
    assert_eq!(a.payload()[5], 16, "flying: EBUSY");
    assert!(said.contains("a trajectory flies from the memory"), "{said}");
    assert_eq!(
        &ask(&mut v, pk(Port::Mem, 1, &read)).payload()[6..],
        &piece[24..48],
        "unchanged"
    );
    // Land from where the trajectory is; then the memory takes writes.
    let mut land = vec![8u8, 0];
    for x in [0.0f32, 0.0] {
        land.extend_from_slice(&x.to_le_bytes());
    }
    land.push(0);
    land.extend_from_slice(&2.0f32.to_le_bytes());
    v.handle(&pk(Port::HighLevel, 0, &land), &mut out).unwrap();
    rest(&mut v, 6500, 100);
    assert!(
        v.flight_loop().setpoint().pos_ned_m[0] > 0.5,
        "the landing starts where the trajectory was"
    );
    assert_eq!(ask(&mut v, mem_write(0, 0, &[0; 24])).payload()[5], 0);
}

/// The flight stack's one write rule ([`fc_loop::Loop::write_param`]) as a
/// Crazyflie's users meet it: armed on the ground the motors are still, so
/// a gain that re-designs is taken; flying a set-point it is refused, said
/// on the console, and the value in force answered; a write that needs no
/// design is taken in flight; landed (the motors stopped), the gain again.
#[test]
fn a_redesigning_write_waits_for_the_motors_to_stop_not_for_a_disarm() {
    let id = find(b"mpc", b"W_POS").to_le_bytes();
    let write = |value: f32| {
        let mut w = vec![id[0], id[1]];
        w.extend_from_slice(&value.to_le_bytes());
        pk(Port::Param, 2, &w)
    };
    let mut v = at_rest(3000);
    let before = crate::f32_at(ask(&mut v, pk(Port::Param, 1, &id)).payload(), 3).unwrap();
    assert_eq!(
        ask(&mut v, pk(Port::Supervisor, 1, &[0x01, 1])).payload(),
        &[0x81, 1, 1]
    );
    assert!(v.armed() && !v.flying());
    let r = ask(&mut v, write(2.0 * before));
    assert_eq!(
        crate::f32_at(r.payload(), 2),
        Some(2.0 * before),
        "armed, motors still: taken"
    );
    let mut out = Sent::default();
    v.handle(&takeoff(0.5, 2.0), &mut out).unwrap();
    assert!(v.flying());
    let (r, said) = ask_said(&mut v, write(3.0 * before));
    assert_eq!(
        crate::f32_at(r.payload(), 2),
        Some(2.0 * before),
        "flying: the value in force"
    );
    assert!(said.contains("MPC.W_POS: disarm first"), "{said}");
    let t = find(b"fs", b"TIMEOUT_MS").to_le_bytes();
    let mut w = vec![t[0], t[1]];
    w.extend_from_slice(&80u16.to_le_bytes());
    let r = ask(&mut v, pk(Port::Param, 2, &w));
    assert_eq!(&r.payload()[2..4], &80u16.to_le_bytes(), "no design: taken in flight");
    assert_eq!(v.flight_loop().settings().failsafe_timeout_ms, 80);
    // The legacy commander's thrust 0 stops the motors, still armed.
    let mut rpyt = vec![0u8; 12];
    rpyt.extend_from_slice(&0u16.to_le_bytes());
    v.handle(&pk(Port::Commander, 0, &rpyt), &mut out).unwrap();
    assert!(v.armed() && !v.flying());
    let r = ask(&mut v, write(3.0 * before));
    assert_eq!(
        crate::f32_at(r.payload(), 2),
        Some(3.0 * before),
        "motors stopped: taken"
    );
}

/// A small generator (SplitMix64), so the fuzz is the same every run.
struct Mix(u64);

impl Mix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
}

/// 10⁶ random and mutated packets (random ports, channels and lengths,
/// wrong TOC ids, full log blocks, NaN set-points): nothing panics, every
/// packet is counted, and a good session works afterwards.
#[test]
fn a_million_bad_packets_are_counted_and_the_session_survives() {
    let mut v = at_rest(3000);
    let mut out = Sent::default();
    v.handle(&pk(Port::Supervisor, 1, &[0x01, 1]), &mut out).unwrap();
    assert!(v.armed());
    // A trajectory of one piece (at rest at 1 m, 1 s) in memory, defined as
    // id 1, for the start seeds below to fly.
    let mut piece = [0u8; 132];
    piece[64..68].copy_from_slice(&1.0f32.to_le_bytes());
    piece[128..].copy_from_slice(&1.0f32.to_le_bytes());
    for (i, chunk) in piece.chunks(24).enumerate() {
        v.handle(&mem_write(0, (i * 24) as u32, chunk), &mut out).unwrap();
    }
    v.handle(&pk(Port::HighLevel, 0, &[6, 1, 1, 0, 0, 0, 0, 0, 1]), &mut out)
        .unwrap();
    // Valid packets of every service, to mutate (no write that re-designs).
    let nan = f32::NAN.to_le_bytes();
    let seeds: Vec<Vec<u8>> = vec![
        vec![0xF1, 0],
        vec![0xD1, 0],
        vec![0xD1, 2],
        vec![0x50, 2, 0, 0],
        vec![0x50, 3],
        vec![0x51, 6, 1, 7, 0, 0, 7, 1, 0, 7, 2, 0],
        vec![0x51, 8, 1, 10, 0],
        vec![0x51, 5],
        vec![0x20, 2, 0x30, 0],
        vec![0x21, 24, 0],
        vec![0x22, 24, 0, 0, 0, 0x48, 0x42],
        vec![0x23, 8, 3, 0],
        vec![0x40, 1],
        vec![0x40, 2, 0],
        vec![0x41, 0, 24, 0, 0, 0, 24],
        vec![0x42, 0, 0, 0, 0, 0, 0, 0, 0x80, 0x3F, 0, 0, 0x80, 0x7F],
        vec![0x80, 6, 1, 1, 0, 0, 0, 0, 0, 1],
        vec![0x80, 13, 0, 1, 0, 0, 1, 0, 0, 0x80, 0x3F],
        vec![0x80, 5, 0, 0, 0, 1, 0, 0, 0x80, 0x3F],
        vec![0x80, 7, 0, 0, 0, 0, 0x3F, 0, 0, 0, 0, 0, 0, 0, 0, 0x40],
        vec![
            0x80, 12, 0, 0, 0, 0, 0, 0, 0x3F, 0, 0, 0, 0, 0, 0, 0x3F, 0, 0, 0, 0, 0, 0, 0x40, 0x40,
        ],
        vec![
            0x70, 7, nan[0], nan[1], nan[2], nan[3], 0, 0, 0, 0, 0, 0, 0x3F, 0, 0, 0, 0,
        ],
        vec![0x71, 0, 0, 0, 0, 0],
        vec![0x60, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        vec![0x90, 0x0C],
        vec![0x30, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
    ];
    let mut g = Mix(42);
    let n = 1_000_000u32;
    let mut buf = [0u8; 40];
    for i in 0..n {
        let len = if i % 2 == 0 {
            // Random: any header, 0–33 bytes.
            let len = (g.next() % 34) as usize;
            for b in buf.iter_mut().take(len) {
                *b = g.next() as u8;
            }
            len
        } else {
            // A seed with one to three bytes changed, sometimes cut or grown.
            let s = &seeds[(g.next() % seeds.len() as u64) as usize];
            let mut len = s.len();
            buf[..len].copy_from_slice(s);
            for _ in 0..1 + g.next() % 3 {
                let at = (g.next() % len as u64) as usize;
                buf[at] = g.next() as u8;
            }
            match g.next() % 4 {
                0 => len = (g.next() % len as u64) as usize,
                1 => len = (len + 1 + (g.next() % 4) as usize).min(33),
                _ => {}
            }
            len
        };
        match Packet::from_bytes(&buf[..len]) {
            Ok(p) => {
                // Every port, but not the emergency stop itself (supervisor
                // or localization, channel 1, command 3): it locks the
                // vehicle until restarted, as it should.
                let stop = matches!(p.port(), 6 | 9) && p.channel() == 1 && p.payload().first() == Some(&3);
                let p = if stop { pk(Port::Supervisor, 0, &[0x0C]) } else { p };
                v.handle(&p, &mut out).unwrap();
            }
            Err(e) => v.count_malformed(e),
        }
        out.0.clear();
        if i % 1000 == 0 {
            rest(&mut v, 3000 + u64::from(i / 1000), 1);
            v.poll(&mut out).unwrap();
        }
    }
    let c = v.counters();
    // The arming, the upload's chunks and the definition before the mix.
    let before = 1 + piece.len().div_ceil(24) as u32 + 1;
    assert_eq!(c.total(), n + before, "every packet counted once: {c:?}");
    assert!(
        c.handled > 0 && c.unsupported > 0 && c.short > 0 && c.malformed > 0,
        "{c:?}"
    );
    // A good session afterwards.
    let src = ask(&mut v, pk(Port::Link, 1, &[0]));
    assert_eq!(&src.payload()[..18], b"Bitcraze Crazyflie");
    let ver = ask(&mut v, pk(Port::Platform, 1, &[0]));
    assert_eq!(ver.payload(), &[0, 12, 0, 0, 0]);
    let r = ask(&mut v, pk(Port::Param, 1, &[0, 0]));
    assert_eq!(&r.payload()[..3], &[0, 0, 0]);
    assert_eq!(ask(&mut v, pk(Port::Mem, 0, &[1])).payload(), &[1, 1]);
}

#[test]
fn a_simulator_writes_the_flight_loops_table_by_index() {
    use fc_loop::params::{index_of, Refusal, PARAMS};
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    let mass = index_of(b"VEH_MASS").unwrap();
    // In range: applied (a re-design, the motors being off), the value in force returned.
    assert_eq!(v.write_param(mass, 0.75), Ok(0.75));
    assert_eq!((PARAMS[mass].get)(v.flight_loop().settings()), 0.75);
    // Out of range or not a number: refused, the value in force kept.
    assert!(matches!(v.write_param(mass, -1.0), Err(Refusal::Range { .. })));
    assert!(matches!(v.write_param(mass, f32::NAN), Err(Refusal::Range { .. })));
    assert_eq!((PARAMS[mass].get)(v.flight_loop().settings()), 0.75);
    // No such entry.
    assert_eq!(v.write_param(PARAMS.len(), 1.0), Err(Refusal::Unknown));
}

/// cfclient's flight tab reads `deck.bc*` (an exception without them): each
/// is in the TOC as the firmware's deck drivers declare it, `PARAM_UINT8 |
/// PARAM_RONLY` (0x48), and reads 0: no deck attached. A write of another
/// value is refused and changes nothing.
#[test]
fn decks_are_read_only_and_absent() {
    let mut v = at_rest(10);
    let decks: Vec<usize> = (0..PARAM_COUNT)
        .filter(|&i| param_entry(i).is_some_and(|(n, _, _)| n.group == "deck"))
        .collect();
    assert_eq!(decks.len(), 8);
    for &i in &decks {
        let (n, t, _) = param_entry(i).unwrap();
        assert_eq!(t, 0x48, "deck.{}", n.name);
        let id = (i as u16).to_le_bytes();
        let r = ask(&mut v, pk(Port::Param, 1, &id));
        // A read's answer: id, status 0, the value.
        assert_eq!(r.payload(), &[id[0], id[1], 0, 0][..], "deck.{} reads 0", n.name);
        let r = ask(&mut v, pk(Port::Param, 2, &[id[0], id[1], 1]));
        assert_eq!(r.payload(), &[id[0], id[1], 0][..], "deck.{} stays 0", n.name);
    }
}

/// A deck reported attached (`report_decks`, as a simulator standing in
/// for a positioning deck does) reads 1 in its own flag only, and every
/// flag stays read-only.
#[test]
fn a_reported_deck_reads_attached_in_its_own_flag_only() {
    use crate::vehicle::DECK_NAMES;
    let mut v = at_rest(10);
    let flow2 = DECK_NAMES.iter().position(|n| *n == "bcFlow2").unwrap();
    v.report_decks(1 << flow2);
    for (bit, name) in DECK_NAMES.iter().enumerate() {
        let id = find(b"deck", name.as_bytes()).to_le_bytes();
        let want = u8::from(bit == flow2);
        let r = ask(&mut v, pk(Port::Param, 1, &id));
        assert_eq!(r.payload(), &[id[0], id[1], 0, want][..], "deck.{name}");
        let r = ask(&mut v, pk(Port::Param, 2, &[id[0], id[1], 1 - want]));
        assert_eq!(r.payload(), &[id[0], id[1], want][..], "deck.{name} is read-only");
    }
}

/// Split as an image splits it (the shared part and the controller in two
/// tasks): a parameter write that re-designs is not answered until the
/// controller's side has run the design; a write that comes meanwhile is
/// refused unanswered (cflib repeats it), and so is a take-off; the answer
/// then carries the value in force, and the same write in one piece
/// (`CrtpVehicle::handle`) is answered at once with the same value.
#[test]
fn a_redesigning_write_is_answered_once_the_controllers_side_has_designed() {
    use crate::vehicle::{fly_step, pass_step, run_work, ControllerWork};
    use fc_loop::Exclusive;
    use nalgebra::Vector4;
    let w_pos = (0..PARAM_COUNT)
        .find(|&i| param_entry(i).is_some_and(|(n, _, _)| n.is(b"mpc", b"W_POS")))
        .unwrap();
    let mut whole = at_rest(3000);
    let mut split = at_rest(3000);
    let id = (w_pos as u16).to_le_bytes();
    let before = crate::f32_at(ask(&mut whole, pk(Port::Param, 1, &id)).payload(), 3).unwrap();
    let mut write = vec![id[0], id[1]];
    write.extend_from_slice(&(2.0 * before).to_le_bytes());
    let write = pk(Port::Param, 2, &write);
    // In one piece: answered at once, with the new value.
    let r = ask(&mut whole, write);
    assert_eq!(crate::f32_at(r.payload(), 2), Some(2.0 * before));

    let (shared, ctrl) = split.split();
    let mut out = Sent::default();
    shared.handle(&write, &mut out).unwrap();
    assert!(
        out.0.iter().all(|p| p.port() != Port::Param as u8),
        "answered before its design"
    );
    let Some(work @ ControllerWork::Param { .. }) = shared.take_work() else {
        panic!("no design queued")
    };
    assert!(work.designs(), "the watchdog's window is widened for it");
    // Meanwhile: a second write and a take-off are refused, unanswered.
    shared.handle(&write, &mut out).unwrap();
    assert!(out.0.iter().all(|p| p.port() != Port::Param as u8));
    assert_eq!(shared.counters().refused, 1);
    assert!(shared.take_work().is_none(), "one design at a time");
    // The estimator's steps go on while the design waits.
    let clock = MonotonicClock::default();
    let imu = ImuSample {
        gyro_frd_radps: Vector3::zeros(),
        accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
    };
    let step = shared.imu_begin(3_001_000, Some(&imu), &[], &clock);
    fly_step(&mut Exclusive(&mut *shared), ctrl, step, &clock);
    // An image lends the controller to the design (at the link's priority):
    // the controller's task passes its steps meanwhile, motors off.
    let step = shared.imu_begin(3_002_000, Some(&imu), &[], &clock);
    assert!(step.job.is_some(), "a step the controller would fly");
    let p = pass_step(&mut Exclusive(&mut *shared), step, &clock);
    assert_eq!(p.u, Vector4::zeros(), "nothing flown without a controller");
    assert_eq!(p.thrusts_n, Vector4::zeros());
    assert_eq!(p.motors.commands, [0.0; 4]);
    assert_eq!(shared.motors(), [0.0; 4]);
    // The controller's side designs; the answer is queued for the link.
    let (r, answer) = run_work(&mut Exclusive(&mut *shared), ctrl, work);
    assert!(r.is_ok() && answer.is_none(), "a CRTP write is answered over CRTP");
    let r = answered_after_design(shared);
    assert_eq!(
        r.payload(),
        ask(&mut whole, write).payload(),
        "the same answer as in one piece"
    );
    assert_eq!(
        shared.counters().handled,
        1,
        "the write, counted once its design is done"
    );
    assert!(!shared.busy());
}

/// The simulator's `ParamSet` on the split vehicle: a write that needs no
/// design is answered at once; one that re-designs is answered by the
/// controller's side, with what our protocol's `Param` carries in one
/// piece; while it waits, another is refused as busy (code 8).
#[test]
fn the_simulators_redesigning_write_is_answered_by_the_controllers_side() {
    use crate::vehicle::run_work;
    use fc_loop::params::{index_of, Refusal};
    use fc_loop::Exclusive;
    use fc_proto::FromFc;
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    let mass = index_of(b"VEH_MASS").unwrap() as u16;
    let timeout = index_of(b"FS_TIMEOUT_MS").unwrap() as u16;
    let (shared, ctrl) = v.split();
    assert!(matches!(
        shared.sim_param(timeout, 300.0),
        Some(FromFc::Param { refusal: 0, .. })
    ));
    assert!(
        shared.sim_param(mass, 0.75).is_none(),
        "a re-design waits for the controller's side"
    );
    let work = shared.take_work().unwrap();
    assert!(matches!(
        shared.sim_param(timeout, 400.0),
        Some(FromFc::Param { refusal: 8, .. })
    ));
    assert_eq!(Refusal::Busy.code(), 8);
    let (r, answer) = run_work(&mut Exclusive(&mut *shared), ctrl, work);
    assert!(r.is_ok());
    let Some(FromFc::Param { value, refusal: 0, .. }) = answer else {
        panic!("{answer:?}")
    };
    assert_eq!(value, 0.75);
    assert_eq!(shared.flight_loop().settings().vehicle.mass_kg, 0.75);
}

/// A take-off forgets the controller's state (`ControllerWork::Reset`)
/// instead of designing it again, which the MPC's design would take tens
/// of milliseconds for. The reset must give what the design gives: every
/// controller the vehicle flies, wound up for 300 steps on the ground
/// (hover asked 1 m above, no motion), then reset, flies the next 100
/// steps bit for bit as a freshly designed one.
#[test]
fn a_reset_controller_flies_as_a_freshly_designed_one() {
    use crate::vehicle::{run_work, ControllerWork};
    use fc_core::control::{Controller, ControllerSpec, Family, Setpoint, StateEstimate};
    use fc_core::model::AttitudeForm;
    use fc_loop::Exclusive;
    use nalgebra::Vector4;
    let on_ground = StateEstimate {
        pos_ned_m: Vector3::zeros(),
        vel_ned_mps: Vector3::zeros(),
        att: Vector4::new(1.0, 0.0, 0.0, 0.0),
        rates_frd_radps: Vector3::zeros(),
    };
    let climbing = |k: usize| StateEstimate {
        pos_ned_m: Vector3::new(0.001 * k as f32, 0.0, -0.002 * k as f32),
        vel_ned_mps: Vector3::new(0.1, 0.0, -0.2),
        ..on_ground
    };
    let up = Setpoint::hold(Vector3::new(0.2, 0.0, -1.0), 0.1);
    for family in [Family::Pd, Family::Lqr, Family::Mpc] {
        for form in [AttitudeForm::Euler, AttitudeForm::Quaternion] {
            let settings = Settings {
                controller: ControllerSpec::new(family, form),
                ..Settings::os4()
            };
            let mut fresh = CrtpVehicle::new(settings).unwrap();
            let mut wound = CrtpVehicle::new(settings).unwrap();
            let (shared, ctrl) = wound.split();
            for _ in 0..300 {
                ctrl.update(&on_ground, &up).unwrap();
            }
            assert!(
                !ControllerWork::Reset.designs(),
                "no design: the watchdog's window stays"
            );
            let (r, _) = run_work(&mut Exclusive(&mut *shared), ctrl, ControllerWork::Reset);
            assert!(r.is_ok());
            let (_, fresh_ctrl) = fresh.split();
            for k in 0..100 {
                let a = ctrl.update(&climbing(k), &up).unwrap().u;
                let b = fresh_ctrl.update(&climbing(k), &up).unwrap().u;
                assert_eq!(a, b, "{family:?} {form:?}, step {k} after the reset");
            }
        }
    }
}

/// `MISC_SETBYNAME` (cflib's `set_value_raw`): `[0, group\0, name\0, type,
/// value]`, answered `[0, group\0, name\0, status]` as the Crazyflie
/// firmware's `paramSetByName` answers: 0 written, ENOENT for no such
/// name, ENOEXEC for a refused value. A write that re-designs is answered
/// the same way once the controller's side has designed (split vehicle).
#[test]
fn a_write_by_name_is_answered_with_its_name_and_status() {
    use crate::vehicle::run_work;
    use fc_loop::Exclusive;
    let by_name = |group: &[u8], name: &[u8], t: u8, value: &[u8]| {
        let mut d = vec![0u8];
        d.extend_from_slice(group);
        d.push(0);
        d.extend_from_slice(name);
        d.push(0);
        d.push(t);
        d.extend_from_slice(value);
        pk(Port::Param, 3, &d)
    };
    let answer = |group: &[u8], name: &[u8], code: u8| {
        let mut a = vec![0u8];
        a.extend_from_slice(group);
        a.push(0);
        a.extend_from_slice(name);
        a.push(0);
        a.push(code);
        a
    };
    let w_pos = (0..PARAM_COUNT)
        .find(|&i| param_entry(i).is_some_and(|(n, _, _)| n.is(b"mpc", b"W_POS")))
        .unwrap();
    let (_, t, _) = param_entry(w_pos).unwrap();
    let mut v = at_rest(3000);
    let r = ask(&mut v, by_name(b"mpc", b"W_POS", t, &3.0f32.to_le_bytes()));
    assert_eq!(r.payload(), &answer(b"mpc", b"W_POS", 0)[..]);
    let r = ask(&mut v, by_name(b"mpc", b"NO_SUCH", t, &3.0f32.to_le_bytes()));
    assert_eq!(r.payload(), &answer(b"mpc", b"NO_SUCH", log::ENOENT)[..]);
    let r = ask(&mut v, by_name(b"mpc", b"W_POS", t, &(-1.0f32).to_le_bytes()));
    assert_eq!(r.payload(), &answer(b"mpc", b"W_POS", log::ENOEXEC)[..]);

    let (shared, ctrl) = v.split();
    let mut out = Sent::default();
    shared
        .handle(&by_name(b"mpc", b"W_POS", t, &4.0f32.to_le_bytes()), &mut out)
        .unwrap();
    assert!(
        out.0.iter().all(|p| p.port() != Port::Param as u8),
        "answered before its design"
    );
    let work = shared.take_work().expect("a design queued");
    let (r, _) = run_work(&mut Exclusive(&mut *shared), ctrl, work);
    assert!(r.is_ok());
    let r = answered_after_design(shared);
    assert_eq!(r.payload(), &answer(b"mpc", b"W_POS", 0)[..]);
}

/// A board's motors take the vehicle's mixer (`CrtpVehicle::mixer`); it
/// follows every parameter write, `MOT_FRAME` included, which changes the
/// rotor layout without a design (no new selection).
#[test]
fn the_mixer_follows_a_motor_layout_write() {
    use fc_loop::params::{index_of, Airframe};
    use nalgebra::Vector4;
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    let selections = v.flight_loop().selections();
    // Hover thrust with a roll torque: each layout spreads it differently.
    let u = Vector4::new(6.0, 0.05, 0.0, 0.0);
    let before = v.mixer().unwrap().thrusts(&u);
    let frame = index_of(b"MOT_FRAME").unwrap();
    assert_eq!(v.write_param(frame, 4.0), Ok(4.0));
    assert_eq!(v.flight_loop().selections(), selections, "no design");
    let expected = Settings {
        airframe: Airframe::XCrazyflie,
        ..Settings::os4()
    }
    .mixer()
    .unwrap()
    .thrusts(&u);
    let after = v.mixer().unwrap().thrusts(&u);
    assert_eq!(after, expected);
    assert_ne!(after, before);
}

/// The parameter answer `shared` sends once its design is done.
fn answered_after_design(shared: &mut crate::vehicle::CrtpShared) -> Packet {
    let mut later = Sent::default();
    shared.poll(&mut later).unwrap();
    *later
        .0
        .iter()
        .find(|p| p.port() == Port::Param as u8)
        .expect("answered after the design")
}

/// The console lines in `sent`.
fn console_of(sent: &[Packet]) -> String {
    sent.iter()
        .filter(|p| p.port() == Port::Console as u8)
        .map(|p| String::from_utf8_lossy(p.payload()).into_owned())
        .collect()
}

/// The console lines `v` has queued.
fn console(v: &mut CrtpVehicle) -> String {
    let mut out = Sent::default();
    v.poll(&mut out).unwrap();
    console_of(&out.0)
}

/// `p` handled: its answer on its port, and the console lines sent with it.
fn ask_said(v: &mut CrtpVehicle, p: Packet) -> (Packet, String) {
    let mut out = Sent::default();
    v.handle(&p, &mut out).unwrap();
    let a = *out.0.iter().rev().find(|a| a.port() == p.port()).expect("an answer");
    (a, console_of(&out.0) + &console(v))
}

/// The supervisor's sensor and battery checks refuse arming by name; a
/// bad or missing IMU sample in flight is replaced by the last good one
/// (the motors never stop for it); more than 10 ms of them starts a
/// failsafe descent that commands do not overrule while the IMU is silent
/// and that lands with the motors off.
#[test]
fn a_silent_imu_in_flight_is_held_for_10_ms_then_a_failsafe_descent() {
    use fc_loop::supervisor::SensorDown;
    let mut v = at_rest(3000);
    v.set_sensors(Err(SensorDown {
        device: "BMI088 gyroscope",
        why: "wrong chip id",
    }));
    let arm = pk(Port::Supervisor, 1, &[0x01, 1]);
    let (a, said) = ask_said(&mut v, arm);
    assert_eq!(a.payload(), &[0x81, 0, 0]);
    assert!(
        said.contains("arming refused: BMI088 gyroscope: wrong chip id"),
        "{said}"
    );
    v.set_sensors(Ok(()));
    v.set_battery(3.1, 3);
    let (a, said) = ask_said(&mut v, arm);
    assert_eq!(a.payload(), &[0x81, 0, 0]);
    assert!(said.contains("arming refused: battery 3.10 V below 3.20 V"), "{said}");
    v.set_battery(3.9, 0);
    assert_eq!(ask(&mut v, arm).payload(), &[0x81, 1, 1]);
    // Take off to 1 m over 2 s; fly 1 s of it.
    let takeoff = takeoff(1.0, 2.0);
    let mut out = Sent::default();
    v.handle(&takeoff, &mut out).unwrap();
    rest(&mut v, 3000, 1000);
    assert!(v.flying());
    let clock = MonotonicClock::default();
    let nan = ImuSample {
        gyro_frd_radps: Vector3::new(f32::NAN, 0.0, 0.0),
        accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
    };
    let mut t_ms = 4001;
    let bad = |v: &mut CrtpVehicle, n: u64, t_ms: &mut u64| {
        let mut outs = Vec::new();
        for _ in 0..n {
            outs.push(v.imu_step(*t_ms * 1000, &nan, &[], &clock));
            *t_ms += 1;
        }
        outs
    };
    // 10 bad samples: each step flies the last good sample; no failsafe.
    let outs = bad(&mut v, 10, &mut t_ms);
    assert!(outs.iter().all(|u| u[0] > 0.1), "the motors kept turning: {outs:?}");
    assert!(v.flying() && !v.failsafe());
    assert_eq!(v.imu_counters().held, 10);
    // The 11th is more than 10 ms after the last good one: failsafe.
    let outs = bad(&mut v, 1, &mut t_ms);
    assert!(outs[0][0] > 0.1 && v.failsafe());
    let said = console(&mut v);
    assert!(
        said.contains("IMU silent for more than 10 ms: failsafe descent"),
        "{said}"
    );
    assert_eq!(v.imu_counters().timeouts, 1);
    // A go_to while silent is overruled: still descending.
    let mut go = vec![12u8, 0, 0, 0];
    for x in [1.0f32, 0.0, 1.0, 0.0, 1.0] {
        go.extend_from_slice(&x.to_le_bytes());
    }
    v.handle(&pk(Port::HighLevel, 0, &go), &mut out).unwrap();
    bad(&mut v, 5, &mut t_ms);
    let sp = v.flight_loop().setpoint().pos_ned_m;
    assert!(sp[0].abs() < 1e-3 && sp[2] > -1.0, "descending where it was: {sp:?}");
    // Good samples again: the descent goes on, to the ground, motors off.
    rest(&mut v, t_ms, 6000);
    assert!(!v.flying() && v.armed(), "landed");
    let said = console(&mut v);
    assert!(said.contains("landed: motors off"), "{said}");
    assert_eq!(v.imu_counters().timeouts, 1);
}

/// The board's barometer (the Crazyflie's BMP388) as a height fix: its
/// first reading, 120 m above sea level, is where the estimator has the
/// vehicle (no jump); a pressure 20 cm higher then pulls the estimate up by
/// as much with no other position source, while a 1 m jump is outside the
/// estimator's gate; readings come at 50 Hz whatever the board offers, and
/// a reading that is not a measurement is not fused.
#[test]
fn the_barometer_is_fused_as_its_change_from_the_first_reading() {
    let mut v = at_rest(2000);
    let clock = MonotonicClock::default();
    let imu = ImuSample {
        gyro_frd_radps: Vector3::zeros(),
        accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
    };
    let p0 = 101_325.0 - 120.0 * 12.0;
    let alt = |p: f32| fc_loop::baro::pressure_altitude_m(p).unwrap();
    let down = |v: &CrtpVehicle| v.flight_loop().navigator().estimate().unwrap().pos_ned_m[2];
    assert!(down(&v).abs() < 0.01);
    // The board offers a reading every ms; 50 Hz are fused.
    let mut fused = 0;
    for k in 2000..3000u64 {
        fused += usize::from(v.baro((k + 1) * 1000, alt(p0)));
        v.imu_step((k + 1) * 1000, &imu, &[], &clock);
    }
    assert_eq!(fused, 50);
    assert_eq!(v.baro_fixes(), 50);
    assert!(down(&v).abs() < 0.02, "no jump at the reference: {}", down(&v));
    // 2.4 Pa less: 0.2 m higher (12.0 Pa/m here). Three seconds of it pull
    // the estimate there (with no other position source the filter's
    // velocity and accelerometer bias take part of it: it overshoots by
    // about 0.1 m over the next 5 s, then settles).
    let rejected = |v: &CrtpVehicle| v.flight_loop().navigator().counters().alt_rejected;
    for k in 3000..6000u64 {
        v.baro((k + 1) * 1000, alt(p0 - 2.4));
        v.imu_step((k + 1) * 1000, &imu, &[], &clock);
    }
    assert!((down(&v) + 0.2).abs() < 0.1, "0.2 m up: {}", down(&v));
    assert_eq!(rejected(&v), 0);
    // A 1 m jump while the IMU says at rest: gated, the estimate stays.
    for k in 6000..6100u64 {
        v.baro((k + 1) * 1000, alt(p0 - 14.4));
        v.imu_step((k + 1) * 1000, &imu, &[], &clock);
    }
    assert!(rejected(&v) >= 4, "{}", rejected(&v));
    assert!((down(&v) + 0.2).abs() < 0.1, "{}", down(&v));
    assert!(!v.baro(6_200_000, f32::NAN));
    assert!(!v.baro(6_300_000, 50_000.0), "50 km is not a measurement");
}

/// A sink whose owner keeps parameters (the RAM stand-in store).
struct Kept {
    sent: Sent,
    store: KeptStore,
}

/// The tests' settings store: 4 KiB of the RAM stand-in.
type KeptStore = fc_storage::Store<fc_storage::RamFlash<4096>>;

/// A [`Kept`] sink over a blank store.
fn kept() -> Kept {
    let (store, _) = fc_storage::Store::open(fc_storage::RamFlash::blank(), 0..4096).unwrap();
    Kept {
        sent: Sent::default(),
        store,
    }
}

/// The store `kept` leaves after a power-off (its flash's bytes are all
/// that is left), opened again, and what opening it found.
fn after_power_off(kept: Kept) -> (KeptStore, fc_storage::Boot) {
    let bytes = *kept.store.into_flash().bytes();
    fc_storage::Store::open(fc_storage::RamFlash::<4096>::holding(&bytes), 0..4096).unwrap()
}

impl CrtpSink for Kept {
    type Error = core::convert::Infallible;
    fn send(&mut self, p: &Packet) -> Result<(), Self::Error> {
        self.sent.send(p)
    }
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        Some(&mut self.store)
    }
}

impl Kept {
    /// The answer to `p` (the last packet sent on its port).
    fn ask(&mut self, v: &mut CrtpVehicle, p: Packet) -> Packet {
        self.sent.0.clear();
        v.handle(&p, self).unwrap();
        *self
            .sent
            .0
            .iter()
            .rev()
            .find(|a| a.port() == p.port())
            .expect("an answer")
    }
}

/// cflib's persistent parameters, byte for byte as its `param.py` sends
/// and reads them (`MISC_GET_EXTENDED_TYPE_V2`, `MISC_PERSISTENT_STORE`,
/// `_GET_STATE`, `_CLEAR`), and a value stored surviving a reboot.
#[test]
fn persistent_parameters_as_cflib_stores_them_survive_a_reboot() {
    let mut kept = kept();
    let mut v = at_rest(3000);
    let w_pos = (0..PARAM_COUNT)
        .find(|&i| param_entry(i).is_some_and(|(n, _, _)| n.is(b"mpc", b"W_POS")))
        .unwrap();
    let (_, t, _) = param_entry(w_pos).unwrap();
    assert_eq!(t, 0x16, "float, extended: cflib asks for the extended type");
    let id = (w_pos as u16).to_le_bytes();
    let misc = |cmd: u8| pk(Port::Param, 3, &[cmd, id[0], id[1]]);
    assert_eq!(kept.ask(&mut v, misc(7)).payload(), &[7, id[0], id[1], 0, 1]);
    let default = {
        let r = kept.ask(&mut v, misc(8));
        f32::from_le_bytes(r.payload()[4..8].try_into().unwrap())
    };
    let state = |r: Packet| r.payload()[3..].to_vec();
    let mut not_stored = vec![0];
    not_stored.extend(default.to_le_bytes());
    assert_eq!(state(kept.ask(&mut v, misc(4))), not_stored);
    let mut w = id.to_vec();
    w.extend(3.0f32.to_le_bytes());
    kept.ask(&mut v, pk(Port::Param, 2, &w));
    assert_eq!(kept.ask(&mut v, misc(3)).payload(), &[3, id[0], id[1], 0]);
    let mut stored = vec![1];
    stored.extend(default.to_le_bytes());
    stored.extend(3.0f32.to_le_bytes());
    assert_eq!(state(kept.ask(&mut v, misc(4))), stored);
    // Not persistent (a Crazyflie name of ours): ENOENT, as the firmware.
    let deck = (0..PARAM_COUNT)
        .find(|&i| param_entry(i).is_some_and(|(n, _, _)| n.group == "deck"))
        .unwrap() as u16;
    let d = deck.to_le_bytes();
    assert_eq!(
        kept.ask(&mut v, pk(Port::Param, 3, &[7, d[0], d[1]])).payload()[3..],
        [0, 0]
    );
    assert_eq!(
        kept.ask(&mut v, pk(Port::Param, 3, &[3, d[0], d[1]])).payload()[3..],
        [log::ENOENT]
    );
    // Without storage: the store fails (EIO), the state is "not stored".
    let r = ask(&mut v, misc(3));
    assert_eq!(r.payload()[3..], [5]);
    let (mut st, boot) = after_power_off(kept);
    assert_eq!(boot, fc_storage::Boot::Found);
    let loaded = fc_loop::params::load(Settings::os4(), |i| st.param(i)).unwrap();
    let mut v = CrtpVehicle::new(loaded.settings).unwrap();
    v.set_defaults(Settings::os4());
    let mut kept = Kept {
        sent: Sent::default(),
        store: st,
    };
    let read = kept.ask(&mut v, pk(Port::Param, 1, &id));
    assert_eq!(read.payload()[3..], 3.0f32.to_le_bytes(), "the stored value in force");
    assert_eq!(state(kept.ask(&mut v, misc(4))), stored);
    assert_eq!(kept.ask(&mut v, misc(5)).payload(), &[5, id[0], id[1], 0]);
    assert_eq!(state(kept.ask(&mut v, misc(4))), not_stored);
}

/// A lookup by name ([`param_named`], which compares lengths first) finds
/// what trying every entry's name finds: each entry by its own name, in
/// the case cflib writes it and in upper case, and nothing for a name one
/// byte longer or shorter.
#[test]
fn a_lookup_by_name_finds_what_every_entrys_name_finds() {
    use crate::vehicle::param_named;
    let scan = |g: &[u8], n: &[u8]| (0..PARAM_COUNT).find(|&i| param_entry(i).is_some_and(|(e, _, _)| e.is(g, n)));
    for id in 0..PARAM_COUNT {
        let (e, _, _) = param_entry(id).unwrap();
        let (g, n) = (e.group.as_bytes(), e.name.as_bytes());
        let upper = g.to_ascii_uppercase();
        let longer = [n, b"x"].concat();
        for (g, n) in [(g, n), (&upper[..], n), (g, &longer[..]), (g, &n[..n.len() - 1])] {
            assert_eq!(param_named(g, n), scan(g, n), "{}.{}", e.group, e.name);
        }
        assert!(param_named(g, n).is_some());
    }
}

/// The param TOC id of `group.name` (cflib compares the group in lower case).
fn find(g: &[u8], n: &[u8]) -> u16 {
    (0..PARAM_COUNT)
        .find(|&i| param_entry(i).is_some_and(|(name, _, _)| name.is(g, n)))
        .unwrap() as u16
}

/// The param TOC declares each parameter's true type: `ctl.ID` is a
/// `uint8_t` and `fs.TIMEOUT_MS` a `uint16_t` (cflib then writes whole
/// numbers, and refuses "5.05" itself), both read and written in their
/// width; a controller id no controller has is refused, and the answer
/// carries the value in force.
#[test]
fn integer_parameters_are_typed_as_integers_in_the_toc() {
    use crate::vehicle::param_types;
    let (ctl, fs, w_pos) = (find(b"ctl", b"ID"), find(b"fs", b"TIMEOUT_MS"), find(b"mpc", b"W_POS"));
    let ty = |i: u16| param_entry(usize::from(i)).unwrap().1;
    assert_eq!(ty(ctl), param_types::U8 | param_types::EXTENDED);
    assert_eq!(ty(fs), param_types::U16 | param_types::EXTENDED);
    assert_eq!(ty(w_pos), param_types::FLOAT | param_types::EXTENDED);

    let mut v = at_rest(3000);
    // Read: [id, status 0, value in its width].
    let read = |v: &mut CrtpVehicle, i: u16| ask(v, pk(Port::Param, 1, &i.to_le_bytes())).payload().to_vec();
    let c = ctl.to_le_bytes();
    let before = read(&mut v, ctl);
    assert_eq!(before.len(), 4, "{before:?}");
    assert_eq!(before[2], 0);
    let f = fs.to_le_bytes();
    assert_eq!(read(&mut v, fs), [f[0], f[1], 0, 50, 0]);
    // Written as a uint16_t, answered and read back as one.
    let r = ask(&mut v, pk(Port::Param, 2, &[f[0], f[1], 200, 0]));
    assert_eq!(r.payload(), &[f[0], f[1], 200, 0]);
    assert_eq!(read(&mut v, fs), [f[0], f[1], 0, 200, 0]);
    // No controller has id 250: refused, the answer is the value in force.
    let r = ask(&mut v, pk(Port::Param, 2, &[c[0], c[1], 250]));
    assert_eq!(r.payload(), &[c[0], c[1], before[3]]);
    assert_eq!(read(&mut v, ctl), before);
}

/// The Crazyflie's names for the flight stack's parameters come from the
/// one table (`Param::crazyflie_alias`): `stabilizer.controller` is
/// `ctl.ID` and `pid_attitude.roll_kp` is `pd.ROLL_P`, each in the table
/// entry's type; a write under either name is read back under the other.
/// No name is in the TOC twice.
#[test]
fn crazyflie_names_are_the_tables_parameters() {
    use crate::vehicle::param_types;
    let (ctl, controller) = (find(b"ctl", b"ID"), find(b"stabilizer", b"controller"));
    let (roll_p, roll_kp) = (find(b"pd", b"ROLL_P"), find(b"pid_attitude", b"roll_kp"));
    let ty = |i: u16| param_entry(usize::from(i)).unwrap().1;
    assert_eq!(ty(controller), param_types::U8);
    assert_eq!(ty(roll_kp), param_types::FLOAT);
    for (g, n) in [
        ("pid_attitude", "roll_kd"),
        ("pid_attitude", "pitch_kp"),
        ("pid_attitude", "yaw_kd"),
    ] {
        find(g.as_bytes(), n.as_bytes());
    }
    let names: Vec<_> = (0..PARAM_COUNT)
        .map(|i| {
            let (n, _, _) = param_entry(i).unwrap();
            (n.group.to_ascii_lowercase(), n.name)
        })
        .collect();
    for (i, n) in names.iter().enumerate() {
        assert!(!names[..i].contains(n), "{n:?} twice");
    }

    let mut v = at_rest(3000);
    let read = |v: &mut CrtpVehicle, i: u16| ask(v, pk(Port::Param, 1, &i.to_le_bytes())).payload()[3..].to_vec();
    let write = |v: &mut CrtpVehicle, i: u16, value: &[u8]| {
        let mut d = i.to_le_bytes().to_vec();
        d.extend_from_slice(value);
        ask(v, pk(Port::Param, 2, &d))
    };
    assert_eq!(read(&mut v, controller), read(&mut v, ctl));
    let gain = 123.5f32.to_le_bytes();
    write(&mut v, roll_kp, &gain);
    assert_eq!(
        read(&mut v, roll_p),
        gain,
        "written as pid_attitude.roll_kp, read as pd.ROLL_P"
    );
    let gain = 99.25f32.to_le_bytes();
    write(&mut v, roll_p, &gain);
    assert_eq!(read(&mut v, roll_kp), gain);
}

/// The log variables read, by name, what they say: the estimate in the
/// Crazyflie's world frame (x forward, y left, z up) and its variances,
/// the heading counter-clockwise in degrees, the set-point, the battery
/// and the supervisor's state; before an estimate, its variables are 0.
#[test]
fn log_variables_read_the_estimate_set_point_and_supervisor_by_name() {
    let at = |g: &str, n: &str| LOG_VARS.iter().position(|x| x.group == g && x.name == n).unwrap();
    let fresh = CrtpVehicle::new(Settings::os4()).unwrap();
    let vals = fresh.log_values();
    for (g, n) in [
        ("stateEstimate", "x"),
        ("stateEstimate", "y"),
        ("stateEstimate", "yaw"),
        ("kalman", "varPZ"),
    ] {
        assert_eq!(vals[at(g, n)].to_bits(), 0, "{g}.{n} before an estimate");
    }

    let v = at_rest(3000);
    let vals = v.log_values();
    let e = v.flight_loop().navigator().estimate().unwrap();
    assert_eq!(vals[at("stateEstimate", "x")], e.pos_ned_m[0]);
    assert_eq!(vals[at("stateEstimate", "y")], -e.pos_ned_m[1]);
    assert_eq!(vals[at("stateEstimate", "z")], -e.pos_ned_m[2]);
    assert_eq!(vals[at("stateEstimate", "vz")], -e.vel_ned_mps[2]);
    let yaw_deg = -e.euler()[2] * 180.0 / core::f32::consts::PI;
    assert!((vals[at("stateEstimate", "yaw")] - yaw_deg).abs() < 1e-4);
    assert_eq!(vals[at("stabilizer", "yaw")], vals[at("stateEstimate", "yaw")]);
    let cov = v.flight_loop().navigator().estimator().covariance();
    assert_eq!(vals[at("kalman", "varPX")], cov[(0, 0)]);
    assert_eq!(vals[at("kalman", "varPZ")], cov[(2, 2)]);
    assert_eq!(vals[at("ctrltarget", "z")], -v.flight_loop().setpoint().pos_ned_m[2]);
    assert_eq!(vals[at("pm", "vbat")], 3.9);
    assert_eq!(vals[at("sys", "armed")], 0.0);
    assert_eq!(vals[at("sys", "canfly")], 1.0);
    assert_eq!(vals[at("motor", "m1")], 0.0);
    assert_eq!(vals[at("supervisor", "info")], f32::from(v.supervisor_bits()));
}

/// The Crazyflie's fixed choices and read-only flags (`EXTRA_PARAMS`)
/// take their one value and refuse any other, naming that value (the
/// range used to name the value refused); the estimator's reset is the
/// flight stack's to refuse while the motors turn
/// ([`fc_loop::Loop::reset_estimation`]).
#[test]
fn fixed_entries_take_one_value_and_a_reset_waits_for_the_motors() {
    let mut v = at_rest(3000);
    let fixed: [(&[u8], &[u8], u8); 3] = [
        (b"stabilizer", b"estimator", 2),
        (b"commander", b"enHighLevel", 1),
        (b"deck", b"bcLedRing", 0),
    ];
    for (g, n, one) in fixed {
        let id = find(g, n).to_le_bytes();
        let (r, said) = ask_said(&mut v, pk(Port::Param, 2, &[id[0], id[1], one + 1]));
        assert_eq!(r.payload().get(2), Some(&one), "the value in force");
        assert!(said.contains(&format!("out of [{one}, {one}]")), "{said}");
        let (r, said) = ask_said(&mut v, pk(Port::Param, 2, &[id[0], id[1], one]));
        assert_eq!(r.payload().get(2), Some(&one));
        assert_eq!(said, "", "its own value is taken");
    }
    let reset = find(b"kalman", b"resetEstimation").to_le_bytes();
    let mut out = arm_and_take_off(&mut v);
    let (_, said) = ask_said(&mut v, pk(Port::Param, 2, &[reset[0], reset[1], 1]));
    assert!(said.contains("kalman.resetEstimation: disarm first"), "{said}");
    assert_eq!(
        v.flight_loop().navigator().mode(),
        fc_loop::nav::NavMode::Navigating,
        "not reset in flight"
    );
    v.handle(&pk(Port::Generic, 0, &[0]), &mut out).unwrap();
    assert!(!v.flying());
    let (_, said) = ask_said(&mut v, pk(Port::Param, 2, &[reset[0], reset[1], 1]));
    assert!(said.contains("estimator reset"), "{said}");
    assert_eq!(
        v.flight_loop().navigator().mode(),
        fc_loop::nav::NavMode::Aligning,
        "reset on the ground"
    );
}

/// Arms `v` (answered as armed) and starts a take-off to 0.5 m: flying.
fn arm_and_take_off(v: &mut CrtpVehicle) -> Sent {
    assert_eq!(ask(v, pk(Port::Supervisor, 1, &[0x01, 1])).payload(), &[0x81, 1, 1]);
    let mut out = Sent::default();
    v.handle(&takeoff(0.5, 2.0), &mut out).unwrap();
    assert!(v.flying());
    out
}

/// `led.bitmask` (what `sbs_swarm.py`'s light check writes: 255, then 0)
/// is a `uint8_t` kept as written and read back, in flight as on the
/// ground; the SIL has no LED, and no flight state changes.
#[test]
fn led_bitmask_is_kept_and_read_back() {
    let mut v = at_rest(3000);
    let id = find(b"led", b"bitmask");
    let (_, t, _) = param_entry(usize::from(id)).unwrap();
    assert_eq!(
        t,
        crate::vehicle::param_types::U8,
        "uint8_t, as the firmware declares it"
    );
    let b = id.to_le_bytes();
    let before = *v.flight_loop().settings();
    for value in [255u8, 128, 0] {
        let (r, said) = ask_said(&mut v, pk(Port::Param, 2, &[b[0], b[1], value]));
        assert_eq!(r.payload(), &[b[0], b[1], value], "the value in force");
        assert_eq!(said, "");
        assert_eq!(
            ask(&mut v, pk(Port::Param, 1, &b)).payload(),
            &[b[0], b[1], 0, value],
            "read back"
        );
    }
    assert_eq!(*v.flight_loop().settings(), before, "no flight setting moved");
    arm_and_take_off(&mut v);
    let (r, _) = ask_said(&mut v, pk(Port::Param, 2, &[b[0], b[1], 255]));
    assert_eq!(r.payload(), &[b[0], b[1], 255], "taken in flight");
    assert!(v.flying());
}

/// `ring.effect`, as `persistent_params.py` flies it: a `uint8_t` marked
/// persistent in the TOC (extended type, then the persistent flag, as the
/// firmware's `PARAM_UINT8 | PARAM_PERSISTENT`), the Crazyflie's default 6,
/// 10 kept and stored under its TOC id, 256 refused; after a power-off the
/// stored 10 is taken at boot (`CrtpVehicle::load_stored`), and a value
/// the write's check refuses stored under it is not.
#[test]
fn ring_effect_persists_as_cflib_stores_it() {
    let mut kept = kept();
    let mut v = at_rest(3000);
    let id = find(b"ring", b"effect");
    let (_, t, _) = param_entry(usize::from(id)).unwrap();
    assert_eq!(t, 0x18, "uint8_t, extended: cflib asks for the extended type");
    let b = id.to_le_bytes();
    let misc = |cmd: u8| pk(Port::Param, 3, &[cmd, b[0], b[1]]);
    assert_eq!(
        kept.ask(&mut v, misc(7)).payload(),
        &[7, b[0], b[1], 0, 1],
        "persistent"
    );
    assert_eq!(kept.ask(&mut v, misc(8)).payload()[3..], [0, 6], "its default");
    assert_eq!(kept.ask(&mut v, misc(4)).payload()[3..], [0, 6], "not stored");
    let (r, said) = ask_said(&mut v, pk(Port::Param, 2, &[b[0], b[1], 10]));
    assert_eq!((r.payload(), said.as_str()), (&[b[0], b[1], 10][..], ""));
    assert_eq!(kept.ask(&mut v, misc(3)).payload(), &[3, b[0], b[1], 0], "stored");
    assert_eq!(
        kept.ask(&mut v, misc(4)).payload()[3..],
        [1, 6, 10],
        "stored 10, default 6"
    );
    // A set by name (cflib's MISC_SETBYNAME) of 256 in a uint16 is refused.
    let mut by_name = vec![0u8];
    by_name.extend(b"ring\0effect\0");
    by_name.extend([crate::vehicle::param_types::U16, 0, 1]);
    let r = kept.ask(&mut v, pk(Port::Param, 3, &by_name));
    assert_ne!(r.payload().last(), Some(&0), "256 refused");
    assert_eq!(ask(&mut v, pk(Port::Param, 1, &b)).payload(), &[b[0], b[1], 0, 10]);
    let (mut st, _) = after_power_off(kept);
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    assert_eq!(v.load_stored(&mut st), Ok((1, 0)));
    assert_eq!(
        ask(&mut v, pk(Port::Param, 1, &b)).payload(),
        &[b[0], b[1], 0, 10],
        "taken at boot"
    );
    st.set_param(id, 300.0).unwrap();
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    assert_eq!(v.load_stored(&mut st), Ok((0, 1)), "300 is no byte: refused, counted");
    assert_eq!(
        ask(&mut v, pk(Port::Param, 1, &b)).payload(),
        &[b[0], b[1], 0, 6],
        "the default stands"
    );
}
