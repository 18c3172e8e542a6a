//! Frames against pymavlink (an implementation this project did not write),
//! refusals of every kind, and a fuzzer.

use super::common::*;
use super::hil::*;
use super::*;
use proptest::prelude::*;

/// pymavlink 2.4 (`dialects.v20.common`), system 42, component 200,
/// sequence 7: `MAVLink_hil_sensor_message(123456789, 0.5, -0.25, -9.81,
/// 0.01, -0.02, 0.03, 0.2, 0.0, 0.4, 1013.25, 0.0, 12.5, 20.0, 7|56|4096)`.
const PYMAVLINK_HIL_SENSOR: [u8; 74] = [
    253, 62, 0, 0, 7, 42, 200, 107, 0, 0, 21, 205, 91, 7, 0, 0, 0, 0, 0, 0, 0, 63, 0, 0, 128, 190, 195, 245, 28, 193,
    10, 215, 35, 60, 10, 215, 163, 188, 143, 194, 245, 60, 205, 204, 76, 62, 0, 0, 0, 0, 205, 204, 204, 62, 0, 80, 125,
    68, 0, 0, 0, 0, 0, 0, 72, 65, 0, 0, 160, 65, 63, 16, 157, 151,
];

/// pymavlink, same header: `MAVLink_hil_actuator_controls_message(42,
/// [0.25, 0.5, 0.75, 1.0] + [0.0] * 12, 128|32|16|8, 1)`.
const PYMAVLINK_HIL_ACTUATOR_CONTROLS: [u8; 93] = [
    253, 81, 0, 0, 7, 42, 200, 93, 0, 0, 42, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 128, 62, 0, 0, 0, 63,
    0, 0, 64, 63, 0, 0, 128, 63, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 184, 183, 240,
];

const HEADER: MavHeader = MavHeader {
    system_id: 42,
    component_id: 200,
    sequence: 7,
};

fn read_all(r: &mut MavReader, bytes: &[u8]) -> Vec<Result<(MavHeader, MavMessage), MavError>> {
    bytes.iter().filter_map(|&b| r.push(b)).collect()
}

fn frame(msg: &MavMessage) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let n = encode(HEADER, msg, &mut out).unwrap();
    out[..n].to_vec()
}

#[test]
fn pymavlinks_hil_sensor_decodes_and_maps_to_an_imu_sample() {
    let mut r = MavReader::new(1);
    let got = read_all(&mut r, &PYMAVLINK_HIL_SENSOR);
    let [Ok((h, MavMessage::HIL_SENSOR(m)))] = &got[..] else {
        panic!("{got:?}")
    };
    assert_eq!((h.system_id, h.component_id, h.sequence), (42, 200, 7));
    let s = imu_from_hil_sensor(m).unwrap();
    assert_eq!(s.time_us, 123_456_789);
    assert_eq!(s.imu.accel_frd_mps2, nalgebra::Vector3::new(0.5, -0.25, -9.81));
    assert_eq!(s.imu.gyro_frd_radps, nalgebra::Vector3::new(0.01, -0.02, 0.03));
    // 4096 flags the temperature (2048 is the pressure altitude): no baro.
    assert_eq!(s.baro_alt_m, None);
    assert_eq!(r.counters().ok, 1);
}

#[test]
fn our_hil_actuator_controls_are_pymavlinks_bytes() {
    let msg = MavMessage::HIL_ACTUATOR_CONTROLS(actuator_controls(42, &[0.25, 0.5, 0.75, 1.0], true));
    assert_eq!(frame(&msg), PYMAVLINK_HIL_ACTUATOR_CONTROLS);
    // Disarmed: the same frame with the motors at zero and no armed flag.
    let MavMessage::HIL_ACTUATOR_CONTROLS(d) =
        MavMessage::HIL_ACTUATOR_CONTROLS(actuator_controls(42, &[1.0; 4], false))
    else {
        unreachable!()
    };
    assert!(d.controls.iter().all(|c| *c == 0.0));
    assert!(!d.mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED));
}

#[test]
fn frames_survive_noise_split_reads_and_back_to_back_delivery() {
    let hb = frame(&MavMessage::HEARTBEAT(heartbeat(false, 0)));
    let mut bytes = vec![0x00, 0x55, 0xFE, 0x12];
    bytes.extend_from_slice(&hb);
    bytes.extend_from_slice(&PYMAVLINK_HIL_SENSOR);
    bytes.extend_from_slice(&[0xAA; 3]);
    bytes.extend_from_slice(&hb);
    let mut r = MavReader::new(1);
    let got = read_all(&mut r, &bytes);
    assert_eq!(got.len(), 3, "{got:?}");
    assert!(got.iter().all(|g| g.is_ok()));
    assert_eq!(r.counters().skipped_bytes, 7);
}

#[test]
fn bad_frames_are_refused_counted_and_the_next_one_reads() {
    let hb = frame(&MavMessage::HEARTBEAT(heartbeat(true, 0)));
    let mut r = MavReader::new(1);
    // A flipped payload bit: the CRC catches it.
    let mut bad = PYMAVLINK_HIL_SENSOR;
    bad[20] ^= 0x04;
    assert_eq!(read_all(&mut r, &bad), vec![Err(MavError::BadCrc)]);
    // An id the dialect does not have (any checksum).
    let mut unknown = hb.clone();
    unknown[7..10].copy_from_slice(&[0x34, 0x12, 0x05]);
    assert_eq!(
        read_all(&mut r, &unknown),
        vec![Err(MavError::UnknownMessage(0x05_1234))]
    );
    // 32-bit system ids are not supported (signed frames are: see `signing`).
    let mut wide = hb.clone();
    wide[2] = 0x02;
    let got = read_all(&mut r, &wide);
    assert_eq!(got[0], Err(MavError::Unsupported(0x02)));
    // A command for system 7 is not for system 1.
    let cmd = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        target_system: 7,
        ..Default::default()
    });
    assert_eq!(read_all(&mut r, &frame(&cmd)), vec![Err(MavError::OtherSystem(7))]);
    // And then a good frame reads.
    assert!(matches!(read_all(&mut r, &hb)[..], [Ok(_)]));
    let c = r.counters();
    assert_eq!(
        (c.bad_crc, c.unknown, c.unsupported, c.other_system, c.ok),
        (1, 1, 1, 1, 1)
    );
    assert!(MavError::BadCrc.to_string().contains("checksum"));
}

#[test]
fn a_buffer_too_small_is_an_error_not_a_panic() {
    let mut out = [0u8; 20];
    let msg = MavMessage::HIL_ACTUATOR_CONTROLS(actuator_controls(1, &[0.5; 4], true));
    assert_eq!(encode(HEADER, &msg, &mut out), Err(MavError::BufferTooSmall));
}

#[test]
fn hil_sensor_without_inertial_fields_or_with_nan_is_refused() {
    let mut m = HIL_SENSOR_DATA {
        fields_updated: HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XACC,
        ..Default::default()
    };
    assert_eq!(imu_from_hil_sensor(&m), Err(HilError::NoInertialData));
    m.fields_updated = HilSensorUpdatedFlags::from_bits_truncate(0x3f);
    m.ygyro = f32::NAN;
    assert_eq!(imu_from_hil_sensor(&m), Err(HilError::Invalid("ygyro")));
    m.ygyro = 0.0;
    m.pressure_alt = 12.5;
    let s = imu_from_hil_sensor(&m).unwrap();
    assert_eq!(s.baro_alt_m, None, "the baro is not flagged");
    m.fields_updated |= HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_PRESSURE_ALT;
    assert_eq!(imu_from_hil_sensor(&m).unwrap().baro_alt_m, Some(12.5));
}

#[test]
fn hil_state_becomes_a_ned_fix_about_home() {
    // Home at 47.4° N; 1e-4° of latitude is 11.13 m north on the sphere,
    // 1e-4° of longitude 11.13·cos 47.4° = 7.53 m east; 2 m up is −2 m down.
    let home = Home {
        lat_e7: 474_000_000,
        lon_e7: 85_000_000,
        alt_mm: 500_000,
    };
    let yaw: f32 = 0.5;
    let m = HIL_STATE_QUATERNION_DATA {
        attitude_quaternion: [(yaw / 2.0).cos(), 0.0, 0.0, (yaw / 2.0).sin()],
        lat: 474_001_000,
        lon: 85_001_000,
        alt: 502_000,
        vx: 150,
        vy: -20,
        vz: 5,
        ..Default::default()
    };
    let f = fix_from_hil_state(&m, &home, &StateFixSigmas::MOCAP_LIKE).unwrap();
    let p = f.pos_ned_m.unwrap();
    let north = 1e-4_f64.to_radians() * EARTH_RADIUS_M;
    let east = north * 47.4_f64.to_radians().cos();
    assert!(
        (f64::from(p[0]) - north).abs() < 1e-3 && (f64::from(p[1]) - east).abs() < 1e-3,
        "{p}"
    );
    assert!((p[2] + 2.0).abs() < 1e-6, "{p}");
    assert_eq!(f.vel_ned_mps.unwrap(), nalgebra::Vector3::new(1.5, -0.2, 0.05));
    assert!((f.yaw_rad.unwrap() - yaw).abs() < 1e-6);
    // Back to WGS-84: the same integers (GLOBAL_POSITION_INT, HOME_POSITION).
    let back = home.geodetic(&nalgebra::Vector3::new(north, east, -2.0));
    assert_eq!(back, (474_001_000, 85_001_000, 502_000));
    assert_eq!(
        home.geodetic(&nalgebra::Vector3::zeros()),
        (474_000_000, 85_000_000, 500_000)
    );
    let bad = HIL_STATE_QUATERNION_DATA {
        attitude_quaternion: [0.0; 4],
        ..m
    };
    assert_eq!(
        fix_from_hil_state(&bad, &home, &StateFixSigmas::MOCAP_LIKE),
        Err(HilError::Invalid("attitude_quaternion"))
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(2000)
    ))]
    /// Random bytes and mutated good frames: never a panic, and a good
    /// frame after any of it is read (a frame's length bounds what the
    /// noise can swallow).
    #[test]
    fn fuzz_the_reader(noise in proptest::collection::vec(any::<u8>(), 0..600),
                       flips in proptest::collection::vec((0usize..74, any::<u8>()), 0..6)) {
        let mut r = MavReader::new(1);
        let mut mutated = PYMAVLINK_HIL_SENSOR;
        for (i, x) in flips {
            mutated[i] ^= x;
        }
        for b in noise.iter().chain(mutated.iter()) {
            let _ = r.push(*b);
        }
        // Flush whatever frame the noise may have started (at most one
        // largest frame), then a good frame must read.
        for _ in 0..MAX_FRAME {
            let _ = r.push(0);
        }
        let got = read_all(&mut r, &PYMAVLINK_HIL_SENSOR);
        prop_assert!(matches!(got[..], [Ok(_)]), "{:?}", got);
    }
}

proptest! {
    /// The magnetic heading of a field seen from any attitude (built with
    /// the model's rotation matrix, not the levelling formula) is the
    /// attitude's heading minus the declination.
    #[test]
    fn mag_heading_is_the_heading_minus_the_declination(
        phi in -0.6f32..0.6, theta in -0.6f32..0.6, psi in -3.1f32..3.1, decl in -0.4f32..0.4, dip in 0.2f32..1.3,
    ) {
        use fc_core::model::{euler_to_quat, quat_to_rotation};
        let (h, v) = (0.5 * libm::cosf(dip), 0.5 * libm::sinf(dip));
        let m_ned = nalgebra::Vector3::new(h * libm::cosf(decl), h * libm::sinf(decl), v);
        let r = quat_to_rotation(&euler_to_quat(phi, theta, psi));
        let m_frd = r.transpose() * m_ned;
        let got = mag_heading_rad(&m_frd, phi, theta).unwrap();
        let err = fc_core::control::wrap_pi(got - (psi - decl));
        prop_assert!(err.abs() < 1e-4, "got {got}, want {}", psi - decl);
    }
}

#[test]
fn a_vertical_field_has_no_heading_and_flags_gate_the_magnetometer() {
    assert_eq!(mag_heading_rad(&nalgebra::Vector3::new(0.0, 0.0, 0.5), 0.0, 0.0), None);
    let inertial = hil::inertial_flags();
    let mut m = HIL_SENSOR_DATA {
        zacc: -9.81,
        xmag: 0.2,
        zmag: 0.4,
        fields_updated: inertial | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XMAG,
        ..Default::default()
    };
    // One axis flagged is not a reading.
    assert_eq!(imu_from_hil_sensor(&m).unwrap().mag_frd_gauss, None);
    m.fields_updated |= HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YMAG | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZMAG;
    assert_eq!(
        imu_from_hil_sensor(&m).unwrap().mag_frd_gauss,
        Some(nalgebra::Vector3::new(0.2, 0.0, 0.4))
    );
    m.ymag = f32::NAN;
    assert_eq!(imu_from_hil_sensor(&m).unwrap().mag_frd_gauss, None);
}

/// Signing against pymavlink 2.4 (its `MAVLinkSigning`: key bytes 0..=31).
mod signing {
    use super::*;
    use crate::signing::{SetupOutcome, SetupRefusal, SignError, Signing, UNSIGNED_ALLOWED};

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    const KEY: [u8; 32] = {
        let mut k = [0u8; 32];
        let mut i = 0;
        while i < 32 {
            k[i] = i as u8;
            i += 1;
        }
        k
    };

    /// pymavlink, system 255, component 190, link 3, timestamp 123456789:
    /// `command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)` (arm).
    const ARM: &str = "fd20010000ffbe4c00000000803f0000000000000000000000000000000000000000000000009001010149d00315cd5b0700004c8962cf42a2";
    /// The same client's next frame (timestamp 123456790): a ground
    /// station's `heartbeat_send(6, 8, 0, 0, 4)`.
    const GCS_HEARTBEAT: &str = "fd09010001ffbe000000000000000608000403ca3e0316cd5b070000355ad8a586f5";
    /// pymavlink as the vehicle (system 1, component 1, sequence 7, link 0,
    /// timestamp 1000): `heartbeat_send(2, 12, 0x81, 0, 4)`.
    const VEHICLE_HEARTBEAT: &str = "fd09010007010100000000000000020c810403c7c600e80300000000982cf5b010eb";

    /// pymavlink's `heartbeat_send(2, 12, 0x81, 0, 4)` (VEHICLE_HEARTBEAT's message).
    fn vehicle_heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
            base_mode: MavModeFlag::from_bits_truncate(0x81),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        })
    }

    fn read(reader: &mut MavReader, s: &mut Signing, frame: &[u8]) -> Option<Result<MavMessage, MavError>> {
        let mut last = None;
        for &b in frame {
            if let Some(r) = reader.push_signed(b, s) {
                last = Some(r.map(|(_, m)| m));
            }
        }
        last
    }

    #[test]
    fn a_pymavlink_signed_arm_is_accepted_with_its_key_and_only_once() {
        let mut s = Signing::with_key(KEY, 0);
        let mut r = MavReader::new(1);
        let m = read(&mut r, &mut s, &hex(ARM)).unwrap().unwrap();
        assert!(
            matches!(m, MavMessage::COMMAND_LONG(c) if c.command == MavCmd::MAV_CMD_COMPONENT_ARM_DISARM && c.param1 == 1.0)
        );
        assert!(s.last_authenticated());
        assert_eq!(s.timestamp(), 123_456_789, "this side's clock follows the newest heard");
        // Replayed: the same frame again.
        let e = read(&mut r, &mut s, &hex(ARM)).unwrap().unwrap_err();
        assert_eq!(e, MavError::Signing(SignError::Replayed));
        // The next frame of the stream is newer.
        assert!(read(&mut r, &mut s, &hex(GCS_HEARTBEAT)).unwrap().is_ok());
        let c = s.counters();
        assert_eq!((c.accepted, c.replayed, c.dropped()), (2, 1, 1));
        assert_eq!(r.counters().signing, 1);
    }

    #[test]
    fn another_key_a_flipped_bit_or_no_signature_is_refused() {
        let mut other = KEY;
        other[31] ^= 1;
        let mut s = Signing::with_key(other, 0);
        let mut r = MavReader::new(1);
        let e = read(&mut r, &mut s, &hex(ARM)).unwrap().unwrap_err();
        assert_eq!(e, MavError::Signing(SignError::BadSignature));
        // A flipped signature bit, right key.
        let mut s = Signing::with_key(KEY, 0);
        let mut f = hex(ARM);
        let n = f.len();
        f[n - 1] ^= 0x80;
        assert_eq!(
            read(&mut r, &mut s, &f).unwrap().unwrap_err(),
            MavError::Signing(SignError::BadSignature)
        );
        // The same arm, unsigned.
        let cmd = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            target_system: 1,
            target_component: 1,
            command: MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
            param1: 1.0,
            ..COMMAND_LONG_DATA::DEFAULT
        });
        let mut buf = [0u8; MAX_FRAME];
        let n = encode(HEADER, &cmd, &mut buf).unwrap();
        assert_eq!(
            read(&mut r, &mut s, &buf[..n]).unwrap().unwrap_err(),
            MavError::Signing(SignError::Unsigned(76))
        );
        assert_eq!(s.counters().unsigned, 1);
        // Without a key everything passes, signed or not.
        let mut open = Signing::new();
        assert!(read(&mut r, &mut open, &buf[..n]).unwrap().is_ok());
        assert!(read(&mut r, &mut open, &hex(ARM)).unwrap().is_ok());
        assert!(!open.last_authenticated());
        assert_eq!(open.counters().dropped(), 0);
    }

    #[test]
    fn a_new_stream_more_than_a_minute_behind_is_a_replay() {
        // This side's clock is 60.01 s past the arm's timestamp.
        let mut s = Signing::with_key(KEY, 123_456_789 + 6_001_000);
        let mut r = MavReader::new(1);
        assert_eq!(
            read(&mut r, &mut s, &hex(ARM)).unwrap().unwrap_err(),
            MavError::Signing(SignError::Replayed)
        );
        // 59.99 s behind: accepted.
        let mut s = Signing::with_key(KEY, 123_456_789 + 5_999_000);
        assert!(read(&mut r, &mut s, &hex(ARM)).unwrap().is_ok());
    }

    #[test]
    fn signed_frames_are_pymavlinks_byte_for_byte() {
        // pymavlink signs with its timestamp, then adds one; ours adds one,
        // then signs.
        let mut s = Signing::with_key(KEY, 999);
        let hb = vehicle_heartbeat();
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 7,
        };
        let mut out = [0u8; MAX_FRAME];
        let n = encode_signed(header, &hb, &mut out, &mut s).unwrap();
        assert_eq!(out[..n], hex(VEHICLE_HEARTBEAT)[..]);
        // Without a key: the plain frame.
        let mut open = Signing::new();
        let m = encode_signed(header, &hb, &mut out, &mut open).unwrap();
        assert_eq!(m, n - 13);
        assert_eq!(out[2], 0);
    }

    #[test]
    fn booted_on_a_stored_key_it_signs_nothing_until_its_owner_is_heard() {
        // The timestamp stored at its last landing (1000) is behind what it
        // signed in the air before a power cut; pymavlink's owner, which
        // keeps the newest timestamp it heard, is above both.
        let mut s = Signing::stored(KEY, 1_000);
        assert!(s.is_on() && !s.may_sign());
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 7,
        };
        let hb = vehicle_heartbeat();
        let text = MavMessage::STATUSTEXT(STATUSTEXT_DATA {
            severity: MavSeverity::MAV_SEVERITY_INFO,
            text: [b'a'; 50].into(),
        });
        let mut out = [0u8; MAX_FRAME];
        // Its heartbeat goes out unsigned, anything else is held.
        let n = encode_signed(header, &hb, &mut out, &mut s).unwrap();
        assert_eq!((out[2] & crate::signing::FLAG_SIGNED, n), (0, 21));
        assert_eq!(encode_signed(header, &text, &mut out, &mut s), Err(MavError::Unclocked));
        // Neither an unsigned frame nor one signed with another key clocks it.
        let mut r = MavReader::new(1);
        let gcs = MavHeader {
            system_id: 255,
            component_id: 190,
            sequence: 0,
        };
        let mut unsigned = [0u8; MAX_FRAME];
        let m = encode(gcs, &hb, &mut unsigned).unwrap();
        let e = read(&mut r, &mut s, &unsigned[..m]).unwrap().unwrap_err();
        assert_eq!(e, MavError::Signing(SignError::Unsigned(0)));
        let mut other = Signing::stored([7; 32], 1_000);
        assert!(read(&mut r, &mut other, &hex(GCS_HEARTBEAT)).unwrap().is_err());
        assert!(!s.may_sign() && !other.may_sign());
        // The owner's signed heartbeat (timestamp 123 456 790) does.
        assert!(read(&mut r, &mut s, &hex(GCS_HEARTBEAT)).unwrap().is_ok());
        assert!(s.may_sign());
        let n = encode_signed(header, &text, &mut out, &mut s).unwrap();
        let mut ts = [0u8; 8];
        ts[..6].copy_from_slice(&out[n - 12..n - 6]);
        assert!(u64::from_le_bytes(ts) > 123_456_790, "{ts:?}");
        // No key stored: nothing to wait for.
        assert!(Signing::stored([0; 32], 0).may_sign());
        // A key given by SETUP_SIGNING comes with its timestamp.
        let mut fresh = Signing::new();
        assert_eq!(fresh.setup(&KEY, 5, false, false), Ok(SetupOutcome::KeySet));
        assert!(fresh.may_sign());
    }

    #[test]
    fn setup_provisions_then_needs_the_key_and_never_while_armed() {
        let mut s = Signing::new();
        assert_eq!(s.setup(&KEY, 5, false, true), Err(SetupRefusal::Armed));
        assert!(!s.is_on());
        assert_eq!(s.setup(&KEY, 5, false, false), Ok(SetupOutcome::KeySet));
        assert_eq!((s.is_on(), s.timestamp()), (true, 5));
        // Changing or clearing it unsigned: refused.
        assert_eq!(
            s.setup(&[7; 32], 9, false, false),
            Err(SetupRefusal::NotSignedWithCurrentKey)
        );
        assert_eq!(
            s.setup(&[0; 32], 0, false, false),
            Err(SetupRefusal::NotSignedWithCurrentKey)
        );
        assert_eq!(s.key(), Some(&KEY));
        // Signed with it: changed, the clock never goes back.
        assert_eq!(s.setup(&[7; 32], 2, true, false), Ok(SetupOutcome::KeySet));
        assert_eq!((s.key(), s.timestamp()), (Some(&[7; 32]), 5));
        assert_eq!(s.setup(&[7; 32], 0, true, true), Err(SetupRefusal::Armed));
        assert_eq!(s.setup(&[0; 32], 0, true, false), Ok(SetupOutcome::Cleared));
        assert!(!s.is_on());
        assert_eq!(s.counters().setups_refused, 4);
        // A blank stored key is no key (PX4's rule).
        assert!(!Signing::with_key([0; 32], 0).is_on());
    }

    #[test]
    fn the_clock_adds_up_microseconds_however_finely_it_is_fed() {
        let mut s = Signing::with_key(KEY, 1);
        for _ in 0..1000 {
            s.advance_us(3);
        }
        assert_eq!(s.timestamp(), 1 + 300);
    }

    #[test]
    fn radio_status_passes_unsigned_as_px4_lets_it() {
        let mut s = Signing::with_key(KEY, 0);
        let mut f = [0u8; 12];
        f[0] = 0xFD;
        for id in UNSIGNED_ALLOWED {
            assert_eq!(s.check(&f, id), Ok(false));
        }
        assert_eq!(s.check(&f, 0), Err(SignError::Unsigned(0)));
        assert_eq!(s.counters().unsigned_allowed, 3);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        /// Whatever bytes arrive, with or without a key: no panic, and with
        /// a key nothing is delivered that was not signed with it.
        #[test]
        fn no_forged_frame_is_delivered(bytes in proptest::collection::vec(any::<u8>(), 0..600), keyed in any::<bool>()) {
            let mut s = if keyed { Signing::with_key(KEY, 0) } else { Signing::new() };
            let mut r = MavReader::new(1);
            for b in bytes {
                if let Some(Ok(_)) = r.push_signed(b, &mut s) {
                    prop_assert!(!keyed || s.last_authenticated(), "an unsigned frame delivered with a key set");
                }
            }
        }
    }
}
