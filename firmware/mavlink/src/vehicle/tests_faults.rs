//! PX4's failure injection as MAVSDK's `Failure` plugin sends it, and the
//! sources' health on the ground (the preflight side; the faults in flight
//! are flown against rotorpy by `tools/mavsdk_failure.py`).

use super::tests::{at_rest, command, command_of, param_set, rest, Sent, Still};

use super::*;
use fc_core::estimate::ImuSample;

/// `MAV_CMD_INJECT_FAILURE` as MAVSDK's `Failure::inject` sends it.
fn inject(unit: f32, failure_type: f32, instance: f32) -> MavMessage {
    command_of(
        MavCmd::MAV_CMD_INJECT_FAILURE,
        [unit, failure_type, instance, 0.0, 0.0, 0.0, 0.0],
    )
}

// MAVLink's FAILURE_UNIT and FAILURE_TYPE.
const GYRO: f32 = 0.0;
const ACCEL: f32 = 1.0;
const MAG: f32 = 2.0;
const BARO: f32 = 3.0;
const GPS: f32 = 4.0;
const OK: f32 = 0.0;
const OFF: f32 = 1.0;
const STUCK: f32 = 2.0;
const GARBAGE: f32 = 3.0;
const WRONG: f32 = 4.0;

/// A vehicle aligned at rest at home, failure injection on.
fn enabled() -> (MavVehicle, u64) {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, 1_000_000, 2000);
    v.handle(&param_set("SYS_FAILURE_EN", 1.0), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(out.param("SYS_FAILURE_EN"), Some(1.0));
    (v, t)
}

/// Off by default, as PX4's: every injection DENIED and said; on, each
/// modelled one ACCEPTED and said, and what is not modelled (a wrong gyro, a
/// garbage barometer, a second GPS, a type that is no whole number)
/// UNSUPPORTED with its reason.
#[test]
fn failure_injection_obeys_only_sys_failure_en_and_refuses_what_is_not_modelled() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    rest(&mut v, &mut out, 1_000_000, 100);
    let mut out = Sent::default();
    v.handle(&inject(GPS, OFF, 0.0), &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_DENIED]);
    assert_eq!(out.texts(), ["failure injection off (SYS_FAILURE_EN 0)"]);
    // Only 0 and 1.
    v.handle(&param_set("SYS_FAILURE_EN", 0.5), &mut out, &Still, 0)
        .unwrap();
    v.handle(&param_set("SYS_FAILURE_EN", 2.0), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(out.param("SYS_FAILURE_EN"), Some(0.0));
    v.handle(&param_set("SYS_FAILURE_EN", 1.0), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(out.param("SYS_FAILURE_EN"), Some(1.0));
    let cases = [
        (
            inject(GYRO, WRONG, 0.0),
            MavResult::MAV_RESULT_UNSUPPORTED,
            "failure refused: fault not modelled here",
        ),
        (
            inject(BARO, GARBAGE, 0.0),
            MavResult::MAV_RESULT_UNSUPPORTED,
            "failure refused: fault not modelled here",
        ),
        (
            inject(BARO, WRONG, 0.0),
            MavResult::MAV_RESULT_UNSUPPORTED,
            "failure refused: fault not modelled here",
        ),
        (
            inject(GPS, 2.5, 0.0),
            MavResult::MAV_RESULT_UNSUPPORTED,
            "failure refused: fault not modelled here",
        ),
        (
            inject(GPS, f32::NAN, 0.0),
            MavResult::MAV_RESULT_UNSUPPORTED,
            "failure refused: fault not modelled here",
        ),
        (
            inject(GPS, OFF, 2.0),
            MavResult::MAV_RESULT_UNSUPPORTED,
            "failure refused: one instance of each sensor here",
        ),
        (
            inject(9.0, OFF, 0.0),
            MavResult::MAV_RESULT_UNSUPPORTED,
            "failure refused: no such sensor here",
        ),
        (
            inject(GPS, OFF, 1.0),
            MavResult::MAV_RESULT_ACCEPTED,
            "failure injected: position fix off",
        ),
        (
            inject(MAG, WRONG, 0.0),
            MavResult::MAV_RESULT_ACCEPTED,
            "failure injected: magnetometer wrong",
        ),
        (
            inject(BARO, STUCK, 0.0),
            MavResult::MAV_RESULT_ACCEPTED,
            "failure injected: barometer stuck",
        ),
        (
            inject(ACCEL, STUCK, 0.0),
            MavResult::MAV_RESULT_ACCEPTED,
            "failure injected: accelerometer stuck",
        ),
        (
            inject(GPS, OK, 0.0),
            MavResult::MAV_RESULT_ACCEPTED,
            "failure injected: position fix ok",
        ),
    ];
    for (m, result, text) in cases {
        let mut out = Sent::default();
        v.handle(&m, &mut out, &Still, 0).unwrap();
        assert_eq!(out.acks(), [result], "{text}");
        assert_eq!(out.texts(), [text]);
    }
}

/// A position fix 5 m north of where the vehicle is, on the ground: the
/// estimator refuses it ten times, the vehicle says so by name and refuses
/// to arm on it; the estimate has not moved. On the ground it is still
/// handed over (a preflight check: in flight it would not be): at 20
/// refusals the estimator believes it (a vehicle carried 5 m is the same
/// to it), and from the first fix fused it is "back" and arms.
#[test]
fn a_position_fix_wrong_by_metres_is_refused_by_name_and_no_arming_on_it() {
    let (mut v, t) = enabled();
    let mut out = Sent::default();
    v.handle(&inject(GPS, WRONG, 0.0), &mut out, &Still, 0).unwrap();
    // 150 ms: 15 fixes, all refused.
    let t = rest(&mut v, &mut out, t, 150);
    let c = v.flight_loop().navigator().counters();
    assert_eq!((c.pos_rejected, c.pos_resets), (15, 0), "{c:?}");
    assert_eq!(
        out.texts(),
        [
            "failure injected: position fix wrong",
            "position fix wrong (10 in a row): not used"
        ]
    );
    let north = v.flight_loop().navigator().estimate().unwrap().pos_ned_m[0];
    assert!(north.abs() < 0.01, "the estimate moved {north} m north");
    let mut out = Sent::default();
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(!v.armed());
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_TEMPORARILY_REJECTED]);
    assert_eq!(out.texts(), ["arming refused: position fix wrong (10 in a row)"]);
    let mut out = Sent::default();
    rest(&mut v, &mut out, t, 200);
    let c = v.flight_loop().navigator().counters();
    assert_eq!(c.pos_resets, 1, "{c:?}");
    assert_eq!(out.texts(), ["position fix back"]);
    let north = v.flight_loop().navigator().estimate().unwrap().pos_ned_m[0];
    assert!((north - 5.0).abs() < 0.05, "the estimate is {north} m north");
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed());
}

/// A position fix that stops (`off`) is silent after 0.5 s, said once;
/// back when it reads again. Stuck at rest on the ground is no fault (a
/// simulator's truth at rest is the same bit for bit), and the stuck fix
/// is still fused.
#[test]
fn a_silent_fix_is_lost_and_back_and_stuck_at_rest_is_no_fault() {
    let (mut v, t) = enabled();
    let mut out = Sent::default();
    v.handle(&inject(GPS, OFF, 0.0), &mut out, &Still, 0).unwrap();
    let t = rest(&mut v, &mut out, t, 480);
    assert_eq!(out.texts(), ["failure injected: position fix off"]);
    let t = rest(&mut v, &mut out, t, 1_000);
    assert_eq!(
        out.texts(),
        [
            "failure injected: position fix off",
            "position fix silent 0.5 s: not used"
        ]
    );
    let mut out = Sent::default();
    v.handle(&inject(GPS, STUCK, 0.0), &mut out, &Still, 0).unwrap();
    let before = v.flight_loop().navigator().counters().pos_fused;
    rest(&mut v, &mut out, t, 2_000);
    assert_eq!(
        out.texts(),
        ["failure injected: position fix stuck", "position fix back"]
    );
    // 100 Hz for 2 s.
    let fused = v.flight_loop().navigator().counters().pos_fused - before;
    assert!((195..=200).contains(&fused), "{fused}");
}

/// At rest with a magnetometer: its heading, turned a quarter (`wrong`)
/// after the first reading set its reference, is refused ten times in a
/// row by the gate on its 1σ and said; a barometer that stops is silent.
#[test]
fn a_wrong_magnetometer_and_a_silent_barometer_are_said_by_name() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let step = |v: &mut MavVehicle, out: &mut Sent, from: u64, n: u64| {
        for k in 0..n {
            let [state, MavMessage::HIL_SENSOR(mut s)] = at_rest(from + k * 1000) else {
                unreachable!()
            };
            (s.xmag, s.ymag, s.zmag, s.pressure_alt) = (0.21, 0.0, 0.43, 480.0);
            s.fields_updated |= HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XMAG
                | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YMAG
                | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZMAG
                | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_PRESSURE_ALT;
            v.handle(&state, out, &Still, 0).unwrap();
            v.handle(&MavMessage::HIL_SENSOR(s), out, &Still, 0).unwrap();
        }
        from + n * 1000
    };
    let t = step(&mut v, &mut out, 1_000_000, 2_000);
    v.handle(&param_set("SYS_FAILURE_EN", 1.0), &mut out, &Still, 0)
        .unwrap();
    let (mags, baros) = (v.counters().mag_fixes, v.counters().baro_fixes);
    assert!(mags > 90 && baros > 90, "{mags} {baros}");
    let mut out = Sent::default();
    v.handle(&inject(MAG, WRONG, 0.0), &mut out, &Still, 0).unwrap();
    v.handle(&inject(BARO, OFF, 0.0), &mut out, &Still, 0).unwrap();
    step(&mut v, &mut out, t, 1_000);
    assert_eq!(
        out.texts(),
        [
            "failure injected: magnetometer wrong",
            "failure injected: barometer off",
            "magnetometer wrong (10 in a row): not used",
            "barometer silent 0.5 s: not used",
        ]
    );
    let psi = v.flight_loop().navigator().estimate().unwrap().euler()[2];
    assert!(psi.abs() < 0.01, "the heading turned to {psi} rad");
    assert_eq!(v.counters().baro_fixes, baros);
}

/// A gyro that stops (`off`) on the ground: every sample is still answered,
/// flown on the last good one; silent after 0.5 s, said by name, and no
/// arming on it; back, and armed, once it reads again.
#[test]
fn a_silent_gyro_is_flown_on_its_last_sample_said_and_refuses_an_arming() {
    let (mut v, t) = enabled();
    let mut out = Sent::default();
    v.handle(&inject(GYRO, OFF, 0.0), &mut out, &Still, 0).unwrap();
    let steps = v.counters().steps;
    let t = rest(&mut v, &mut out, t, 1_000);
    assert_eq!(v.counters().steps - steps, 1_000, "every sample answered");
    assert_eq!(
        out.texts(),
        ["failure injected: gyro off", "gyro silent 0.5 s: not used"]
    );
    let mut out = Sent::default();
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(!v.armed());
    assert_eq!(out.texts(), ["arming refused: gyro silent 0.5 s"]);
    let mut out = Sent::default();
    v.handle(&inject(GYRO, OK, 0.0), &mut out, &Still, 0).unwrap();
    rest(&mut v, &mut out, t, 10);
    assert_eq!(out.texts(), ["failure injected: gyro ok", "gyro back"]);
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed());
}

/// An accelerometer that stops (`off`): a step in the air flies the
/// specific force the commanded thrust gives in its place (what the
/// caller hands over; `sensors.rs` hands `(0, 0, −U1/m)` in the air and
/// nothing on the ground), one on the ground the mean of its good
/// readings (the rest's −9.81 m/s² on z); the gyro is untouched.
#[test]
fn a_silent_accelerometer_is_replaced_by_the_thrust_in_the_air_and_its_mean_on_the_ground() {
    let (mut v, t) = enabled();
    let mut out = Sent::default();
    v.handle(&inject(ACCEL, OFF, 0.0), &mut out, &Still, 0).unwrap();
    let read = ImuSample {
        gyro_frd_radps: Vector3::new(0.01, -0.02, 0.03),
        accel_frd_mps2: Vector3::new(1.0, 2.0, 3.0),
    };
    let thrust = Vector3::new(0.0, 0.0, -12.5);
    let air = v.shared.faults.imu(t, &read, || Some(thrust)).unwrap();
    assert_eq!(air.accel_frd_mps2, thrust);
    assert_eq!(air.gyro_frd_radps, read.gyro_frd_radps);
    let ground = v.shared.faults.imu(t + 1_000, &read, || None).unwrap();
    let want = Vector3::new(0.0, 0.0, -9.81);
    assert!(
        (ground.accel_frd_mps2 - want).norm() < 1e-3,
        "{:?}",
        ground.accel_frd_mps2
    );
}

/// Steps `v` at rest at 1 kHz from `from_us` for `n` samples whose IMU
/// reads with noise: a BMI088's at rest (its datasheet's 0.014 °/s and
/// 175 µg, 1σ), uniform from a seeded generator (`seed`).
fn noisy_rest(v: &mut MavVehicle, out: &mut Sent, from_us: u64, n: u64, seed: u64) -> u64 {
    let mut x = seed;
    let mut noise = |sigma: f32| {
        x = x
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        // Uniform on ±√3σ: its 1σ is σ.
        ((x >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 2.0 * 3f32.sqrt() * sigma
    };
    let (gyro, accel) = (0.014f32.to_radians(), 175e-6 * 9.81);
    for k in 0..n {
        for mut m in at_rest(from_us + k * 1000) {
            if let MavMessage::HIL_SENSOR(s) = &mut m {
                s.xgyro += noise(gyro);
                s.ygyro += noise(gyro);
                s.zgyro += noise(gyro);
                s.xacc += noise(accel);
                s.yacc += noise(accel);
                s.zacc += noise(accel);
            }
            v.handle(&m, out, &Still, 0).unwrap();
        }
    }
    from_us + n * 1000
}

/// An IMU part stuck on the ground: one that has read with noise and then
/// reads 20 equal in a row refuses an arming by name (PX4's
/// preflight "stale" sensor), the accelerometer's and the gyro's; cleared,
/// it reads with noise again and the vehicle arms. A noiseless IMU at rest
/// (a simulator's) reads the same for seconds and has never read with
/// noise: stuck or not, it arms, so this is found only on a noisy IMU.
#[test]
fn an_imu_stuck_on_the_ground_refuses_an_arming_once_it_had_read_with_noise() {
    for (unit, name) in [(ACCEL, "accelerometer"), (GYRO, "gyro")] {
        let (mut v, t) = enabled();
        let mut out = Sent::default();
        let t = noisy_rest(&mut v, &mut out, t, 100, 7);
        v.handle(&inject(unit, STUCK, 0.0), &mut out, &Still, 0).unwrap();
        let t = noisy_rest(&mut v, &mut out, t, 100, 8);
        let mut out = Sent::default();
        v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
        assert!(!v.armed(), "{name}");
        assert_eq!(out.texts(), [format!("arming refused: {name} stuck (20 the same)")]);
        let mut out = Sent::default();
        v.handle(&inject(unit, OK, 0.0), &mut out, &Still, 0).unwrap();
        noisy_rest(&mut v, &mut out, t, 10, 9);
        v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
        assert!(v.armed(), "{name}: {:?}", out.texts());
    }
    // Noiseless: the same injection, and it arms.
    let (mut v, t) = enabled();
    let mut out = Sent::default();
    v.handle(&inject(ACCEL, STUCK, 0.0), &mut out, &Still, 0).unwrap();
    rest(&mut v, &mut out, t, 100);
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed(), "{:?}", out.texts());
}
