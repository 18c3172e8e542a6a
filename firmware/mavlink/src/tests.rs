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
    // Signed frames are not supported.
    let mut signed = hb.clone();
    signed[2] = 0x01;
    let got = read_all(&mut r, &signed);
    assert_eq!(got[0], Err(MavError::Unsupported(0x01)));
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
