//! Syslink framing against the firmware's `uart_syslink.c` (start bytes,
//! Fletcher-8 over type, length and data; length ≤ 64), the radio's one
//! downlink per uplink, battery reports, and 10⁶ random and mutated frames.

use super::*;
use crate::vehicle::CrtpVehicle;
use crate::vehicle::LOG_VARS;
use fc_loop::params::Settings;

/// What the STM32 wrote to the nRF51.
#[derive(Default)]
struct Wire(Vec<u8>);

impl ByteLink for Wire {
    type Error = core::convert::Infallible;
    fn read(&mut self, _: &mut [u8]) -> Result<usize, Self::Error> {
        Ok(0)
    }
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.extend_from_slice(bytes);
        Ok(())
    }
}

fn frame(ty: u8, data: &[u8]) -> Vec<u8> {
    let mut out = [0u8; FRAME_MAX];
    let n = SyslinkPacket::new(ty, data).unwrap().encode(&mut out);
    out[..n].to_vec()
}

/// The frames in `bytes`.
fn frames(bytes: &[u8]) -> Vec<SyslinkPacket> {
    let mut d = Decoder::new();
    bytes.iter().filter_map(|&b| d.push(b)).map(|r| r.unwrap()).collect()
}

#[test]
fn frames_are_the_firmwares() {
    // RADIO_READY, empty: ckA = 0x0B, ckB = 0x0B + 0x0B (by hand, as
    // syslinkSendPacket sums type and length).
    assert_eq!(frame(types::RADIO_READY, &[]), [0xBC, 0xCF, 0x0B, 0x00, 0x0B, 0x16]);
    // A null CRTP packet in RADIO_RAW: type 0, length 1, data 0xFF:
    // ckA 0 → 1 → 0x00 (0x1 + 0xFF), ckB 0 → 1 → 1.
    assert_eq!(
        frame(types::RADIO_RAW, &[0xFF]),
        [0xBC, 0xCF, 0x00, 0x01, 0xFF, 0x00, 0x01]
    );
    // Junk before a frame, a repeated first start byte, then the frame.
    let mut bytes = vec![0x00, 0xCF, 0xBC, 0xBC];
    bytes.extend_from_slice(&frame(types::RADIO_RAW, b"\x3Chello")[1..]);
    let got = frames(&bytes);
    assert_eq!(got.len(), 1);
    assert_eq!(got[0].data(), b"\x3Chello");
    // A bad checksum and a length over 64 are dropped, and the decoder
    // takes the next frame.
    let mut d = Decoder::new();
    let mut bad = frame(types::RADIO_RAW, &[1, 2, 3]);
    *bad.last_mut().unwrap() ^= 1;
    let r: Vec<_> = bad.iter().filter_map(|&b| d.push(b)).collect();
    assert_eq!(r, [Err(SyslinkError::Checksum(0))]);
    let r: Vec<_> = [0xBC, 0xCF, 0x00, 65].iter().filter_map(|&b| d.push(b)).collect();
    assert_eq!(r, [Err(SyslinkError::TooLong(65))]);
    let ok = frame(types::PM_BATTERY_STATE, &[0; 9]);
    assert!(matches!(ok.iter().filter_map(|&b| d.push(b)).next(), Some(Ok(_))));
    assert_eq!(SyslinkPacket::new(0, &[0; 65]), Err(SyslinkError::TooLong(65)));
}

#[test]
fn one_downlink_packet_answers_each_uplink_packet() {
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    let mut s: Syslink<8> = Syslink::new();
    let mut w = Wire::default();
    s.boot(&mut w).unwrap();
    assert_eq!(w.0, frame(types::RADIO_READY, &[]));
    w.0.clear();
    // The nRF51 echoes RADIO_READY: no answer.
    s.receive(&frame(types::RADIO_READY, &[]), &mut v, &mut w).unwrap();
    assert!(w.0.is_empty());
    // A link echo, carried in RADIO_RAW, answered in RADIO_RAW.
    let echo = [0xF0, b'p', b'i', b'n', b'g'];
    s.receive(&frame(types::RADIO_RAW, &echo), &mut v, &mut w).unwrap();
    let got = frames(&w.0);
    assert_eq!(got.len(), 1);
    assert_eq!((got[0].ty(), got[0].data()), (types::RADIO_RAW, &echo[..]));
    w.0.clear();
    // A null packet (the radio polling) with nothing queued: no answer.
    s.receive(&frame(types::RADIO_RAW, &[0xFF]), &mut v, &mut w).unwrap();
    assert!(w.0.is_empty());
    // Two requests in one burst: the second answer waits for the next uplink.
    let ver = [0xD1, 0];
    let mut burst = frame(types::RADIO_RAW, &ver);
    burst.extend(frame(types::RADIO_RAW, &[0xF1, 0]));
    s.receive(&burst, &mut v, &mut w).unwrap();
    let got = frames(&w.0);
    assert_eq!(got.len(), 2, "one answer per uplink packet");
    assert_eq!(got[0].data(), &[0xD1, 0, 12, 0, 0, 0], "platform protocol version 12");
    assert_eq!(&got[1].data()[1..19], b"Bitcraze Crazyflie");
    w.0.clear();
    // A broadcast is acted on but not answered.
    s.receive(&frame(types::RADIO_RAW_BROADCAST, &[0xF0, 1]), &mut v, &mut w)
        .unwrap();
    assert!(w.0.is_empty());
    s.receive(&frame(types::RADIO_RAW, &[0xFF]), &mut v, &mut w).unwrap();
    assert_eq!(
        frames(&w.0)[0].data(),
        &[0xF0, 1],
        "the broadcast's echo waited in the queue"
    );
    let c = s.counters();
    assert_eq!((c.frames, c.radio, c.ready, c.downlink_sent), (7, 6, 1, 4));
}

#[test]
fn the_battery_comes_from_the_radio_chip() {
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    let mut s: Syslink<8> = Syslink::new();
    let mut w = Wire::default();
    let vbat = LOG_VARS
        .iter()
        .position(|l| (l.group, l.name) == ("pm", "vbat"))
        .unwrap();
    let state = LOG_VARS
        .iter()
        .position(|l| (l.group, l.name) == ("pm", "state"))
        .unwrap();
    let report = BatteryState {
        flags: 0b011,
        vbat_v: 3.71,
        charge_current_a: 0.2,
    };
    s.receive(&frame(types::PM_BATTERY_STATE, &report.to_bytes()), &mut v, &mut w)
        .unwrap();
    assert_eq!(v.log_values()[vbat], 3.71);
    assert_eq!(v.log_values()[state], 1.0, "charging");
    // NaN, short, absurd: refused, the last good value stays.
    let mut nan = report.to_bytes();
    nan[1..5].copy_from_slice(&f32::NAN.to_le_bytes());
    let absurd = BatteryState {
        vbat_v: 400.0,
        ..report
    };
    for bad in [&nan[..], &report.to_bytes()[..8], &absurd.to_bytes()[..]] {
        s.receive(&frame(types::PM_BATTERY_STATE, bad), &mut v, &mut w).unwrap();
    }
    assert_eq!(v.log_values()[vbat], 3.71);
    assert_eq!((s.counters().battery, s.counters().bad_battery), (1, 3));
    assert!(w.0.is_empty());
}

/// 10⁶ frames: random bytes, and valid frames mutated (a byte changed,
/// cut, a wrong length or checksum, NaN batteries, CRTP packets of every
/// port). No panic; every frame taken is counted in exactly one kind and
/// every radio packet reaches the vehicle's counters; a good session
/// afterwards.
#[test]
fn a_million_bad_frames_are_counted_and_the_link_survives() {
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    let mut s: Syslink<8> = Syslink::new();
    let mut w = Wire::default();
    let nan = f32::NAN.to_le_bytes();
    let seeds: Vec<Vec<u8>> = vec![
        frame(types::RADIO_RAW, &[0xFF]),
        frame(types::RADIO_RAW, &[0xF1, 0]),
        frame(types::RADIO_RAW, &[0xD1, 0]),
        frame(types::RADIO_RAW, &[0x21, 24, 0]),
        frame(types::RADIO_RAW, &[0x51, 6, 1, 7, 0, 0, 7, 1, 0, 7, 2, 0]),
        frame(types::RADIO_RAW, &[0x70, 7, nan[0], nan[1], nan[2], nan[3], 0, 0, 0, 0]),
        frame(
            types::RADIO_RAW,
            &[0x80, 7, 0, 0, 0, 0, 0x3F, 0, 0, 0, 0, 0, 0, 0, 0, 0x40],
        ),
        frame(types::RADIO_RAW, &[0x5A; 31]),
        frame(types::RADIO_RAW_BROADCAST, &[0x70, 0]),
        frame(types::RADIO_READY, &[]),
        frame(
            types::PM_BATTERY_STATE,
            &[0, nan[0], nan[1], nan[2], nan[3], 0, 0, 0, 0],
        ),
        frame(types::PM_BATTERY_STATE, &[1, 0, 0, 0x70, 0x40, 0, 0, 0, 0]),
        frame(0x30, &[]),
        frame(types::RADIO_RAW, &[0x20; 64]),
    ];
    let mut g = 0x5EED_u64;
    let mut next = move || {
        // SplitMix64.
        g = g.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = g;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    };
    let n = 1_000_000u32;
    let mut buf = Vec::with_capacity(80);
    for i in 0..n {
        buf.clear();
        if i % 4 == 0 {
            // Random bytes, start bytes likely.
            for _ in 0..next() % 72 {
                let r = next();
                buf.push(if r % 5 == 0 {
                    START[(r >> 8) as usize % 2]
                } else {
                    (r >> 16) as u8
                });
            }
        } else {
            buf.extend_from_slice(&seeds[(next() % seeds.len() as u64) as usize]);
            match next() % 4 {
                0 => {
                    let at = (next() % buf.len() as u64) as usize;
                    buf[at] = next() as u8;
                }
                1 => {
                    let keep = (next() % buf.len() as u64) as usize;
                    buf.truncate(keep);
                }
                _ => {}
            }
        }
        s.receive(&buf, &mut v, &mut w).unwrap();
        w.0.clear();
        if i % 1000 == 0 {
            s.poll(&mut v);
        }
    }
    let c = s.counters();
    assert_eq!(
        c.frames,
        c.radio + c.ready + c.battery + c.bad_battery + c.unhandled,
        "every frame taken counted in one kind: {c:?}"
    );
    assert_eq!(v.counters().total(), c.radio, "every radio packet reached the vehicle");
    assert!(
        c.bad_frames > 100_000 && c.radio > 100_000 && c.bad_battery > 0 && c.unhandled > 0,
        "{c:?}"
    );
    // A good session afterwards: the decoder resynchronises within one
    // frame's length of bytes without a start byte.
    s.receive(&[0; FRAME_MAX], &mut v, &mut w).unwrap();
    for _ in 0..8 {
        s.receive(&frame(types::RADIO_RAW, &[0xFF]), &mut v, &mut w).unwrap();
    }
    w.0.clear();
    s.receive(&frame(types::RADIO_RAW, &[0xD1, 0]), &mut v, &mut w).unwrap();
    let got = frames(&w.0);
    assert_eq!(got.len(), 1);
    assert_eq!(got[0].data(), &[0xD1, 0, 12, 0, 0, 0]);
}

/// cflib's persistent store through syslink: answered with the storage the
/// link keeps (outside the vehicle's lock), EIO without one.
#[test]
fn persistent_parameters_are_answered_with_the_links_storage() {
    use crate::vehicle::{param_entry, PARAM_COUNT};
    let mut v = CrtpVehicle::new(Settings::os4()).unwrap();
    let id = (0..PARAM_COUNT)
        .find(|&i| param_entry(i).is_some_and(|(n, _, _)| n.is(b"mpc", b"W_POS")))
        .unwrap() as u16;
    let [lo, hi] = id.to_le_bytes();
    let ask = |s: &mut Syslink<8>, v: &mut CrtpVehicle, cmd: u8| {
        let mut w = Wire::default();
        s.receive(&frame(types::RADIO_RAW, &[0x23, cmd, lo, hi]), v, &mut w)
            .unwrap();
        frames(&w.0)[0].data().to_vec()
    };
    let mut bare: Syslink<8> = Syslink::new();
    assert_eq!(ask(&mut bare, &mut v, 3), [0x23, 3, lo, hi, crate::log::EIO]);
    let (store, _) = fc_storage::Store::open(fc_storage::RamFlash::<2048>::blank(), 0..2048).unwrap();
    let store: &'static mut _ = Box::leak(Box::new(store));
    let mut s: Syslink<8> = Syslink::new();
    s.keep_in(store);
    assert_eq!(ask(&mut s, &mut v, 3), [0x23, 3, lo, hi, 0]);
    let state = ask(&mut s, &mut v, 4);
    assert_eq!(state[..5], [0x23, 4, lo, hi, 1], "stored");
    assert_eq!(state[5..9], state[9..13], "the default stored: value and default alike");
}
