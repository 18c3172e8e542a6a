//! The MAVLink vehicle against analytic truth (hover motor speeds), the
//! protocols' rules (every `HIL_SENSOR` answered once, the old value echoed
//! on a refused write), its telemetry rates, and a fuzzer of ≥ 10⁶ frames.

use super::*;
use crate::{encode, MavHeader, MavReader, MAX_FRAME};
use core::convert::Infallible;
use fc_core::model::VehicleParams;
use hal_shim::CycleClock;

/// A clock that does not count (cycles are not the subject here).
pub(super) struct Still;
impl CycleClock for Still {
    fn now(&self) -> u32 {
        0
    }
    fn hz(&self) -> u32 {
        168_000_000
    }
}

/// Everything the vehicle sent, with whom to.
#[derive(Default)]
pub(super) struct Sent(pub(super) Vec<(Peer, MavMessage)>);

impl MavSink for Sent {
    type Error = Infallible;
    fn send(&mut self, to: Peer, msg: &MavMessage) -> Result<(), Infallible> {
        self.0.push((to, msg.clone()));
        Ok(())
    }
}

impl Sent {
    fn count(&self, name: &str) -> usize {
        self.0.iter().filter(|(_, m)| message_name(m) == name).count()
    }
    pub(super) fn texts(&self) -> Vec<String> {
        self.0
            .iter()
            .filter_map(|(_, m)| match m {
                MavMessage::STATUSTEXT(t) => {
                    let len = t.text.iter().position(|&b| b == 0).unwrap_or(50);
                    Some(String::from_utf8_lossy(&t.text[..len]).into_owned())
                }
                _ => None,
            })
            .collect()
    }
    /// Asserts that a STATUSTEXT saying exactly `text` was sent.
    pub(super) fn assert_text(&self, text: &str) {
        let texts = self.texts();
        assert!(texts.iter().any(|t| t == text), "{text:?} not among {texts:?}");
    }
    /// What `f` picks from each message sent, in order.
    fn pick<T>(&self, f: impl Fn(&MavMessage) -> Option<T>) -> Vec<T> {
        self.0.iter().filter_map(|(_, m)| f(m)).collect()
    }
    pub(super) fn acks(&self) -> Vec<MavResult> {
        self.pick(|m| match m {
            MavMessage::COMMAND_ACK(a) => Some(a.result),
            _ => None,
        })
    }
    pub(super) fn param(&self, id: &str) -> Option<f32> {
        self.0.iter().rev().find_map(|(_, m)| match m {
            MavMessage::PARAM_VALUE(p) if p.param_id.to_str().ok()?.trim_end_matches('\0') == id => Some(p.param_value),
            _ => None,
        })
    }
}

fn message_name(m: &MavMessage) -> &'static str {
    use mavlink::Message;
    m.message_name()
}

/// At rest on the ground at home, level, heading north.
pub(super) fn at_rest(t_us: u64) -> [MavMessage; 2] {
    let flags = hil::inertial_flags();
    [
        MavMessage::HIL_STATE_QUATERNION(HIL_STATE_QUATERNION_DATA {
            time_usec: t_us,
            attitude_quaternion: [1.0, 0.0, 0.0, 0.0],
            lat: 474_000_000,
            lon: 85_000_000,
            alt: 500_000,
            ..Default::default()
        }),
        MavMessage::HIL_SENSOR(HIL_SENSOR_DATA {
            time_usec: t_us,
            zacc: -9.81,
            fields_updated: flags,
            ..Default::default()
        }),
    ]
}

/// Steps `v` at rest at 1 kHz from `from_us` for `n` samples.
pub(super) fn rest(v: &mut MavVehicle, out: &mut Sent, from_us: u64, n: u64) -> u64 {
    for k in 0..n {
        for m in at_rest(from_us + k * 1000) {
            v.handle(&m, out, &Still, 0).unwrap();
        }
    }
    from_us + n * 1000
}

pub(super) fn command(arm: f32, force: f32) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        param1: arm,
        param2: force,
        command: MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
        target_system: 1,
        target_component: 1,
        ..Default::default()
    })
}

/// A `COMMAND_LONG` for this vehicle.
pub(super) fn command_of(command: MavCmd, p: [f32; 7]) -> MavMessage {
    MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        param1: p[0],
        param2: p[1],
        param3: p[2],
        param4: p[3],
        param5: p[4],
        param6: p[5],
        param7: p[6],
        command,
        target_system: 1,
        target_component: 1,
        ..Default::default()
    })
}

/// `MAV_CMD_DO_SET_MODE` as MAVSDK sends it (custom mode enabled, PX4's
/// main and sub mode).
fn set_mode(m: FlightMode) -> MavMessage {
    let (main, sub) = m.px4();
    command_of(
        MavCmd::MAV_CMD_DO_SET_MODE,
        [1.0, f32::from(main), f32::from(sub), 0.0, 0.0, 0.0, 0.0],
    )
}

pub(super) fn param_set(id: &str, value: f32) -> MavMessage {
    MavMessage::PARAM_SET(PARAM_SET_DATA {
        param_value: value,
        target_system: 1,
        target_component: 1,
        param_id: id.into(),
        param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
    })
}

#[test]
fn the_parameter_table_is_well_formed_and_every_value_reads_back() {
    let s = Settings::os4();
    for (i, p) in PARAMS.iter().enumerate() {
        assert!(p.id.len() <= 16 && p.id.is_ascii(), "{}", p.id);
        assert_eq!(params::index_of(p.id.as_bytes()), Some(i), "{} is not unique", p.id);
        // Writing the value it has changes nothing; NaN is refused.
        assert_eq!(params::write(&s, i, (p.get)(&s)), Ok(s), "{}", p.id);
        assert!(params::write(&s, i, f32::NAN).is_err(), "{} took NaN", p.id);
    }
    // A NUL-padded name (as MAVLink sends it) is found; an unknown one is not.
    let mut padded = [0u8; 16];
    padded[..8].copy_from_slice(b"VEH_MASS");
    assert_eq!(params::index_of(&padded), Some(0));
    assert_eq!(params::index_of(b"VEH_MASSX"), None);
}

#[test]
fn numbers_print_in_six_significant_digits_and_parse_back() {
    use params::Num;
    for (x, want) in [
        (0.01, "0.01"),
        (100.0, "100"),
        (-1.0, "-1"),
        (0.65, "0.65"),
        (1e-7, "1e-7"),
        (1.5e-7, "1.5e-7"),
        (2.5e6, "2.5e6"),
        (123456.0, "123456"),
        (0.00123, "0.00123"),
        (0.000123, "1.23e-4"),
        (9.999999, "10"),
        (0.0, "0"),
        (f32::NAN, "NaN"),
        (f32::NEG_INFINITY, "-inf"),
        (f32::MAX, "3.40282e38"),
        // Exact ties at the sixth digit round away from zero (one rounding,
        // not two: dividing by 10^5 first lost them).
        (-969765.5, "-969766"),
        (9848555.0, "9.84856e6"),
        (f32::from_bits(1), "1.4013e-45"),
    ] {
        assert_eq!(Num(x).to_string(), want, "{x}");
    }
    // Parsed back (by Rust), within half a unit of the sixth digit.
    let mut rng = Rng(7);
    for _ in 0..10_000 {
        let x = f32::from_bits(rng.next() as u32);
        if !x.is_finite() {
            continue;
        }
        let ours: f64 = Num(x).to_string().parse().unwrap();
        let rel = ((ours - f64::from(x)) / f64::from(x)).abs();
        assert!(x == 0.0 || rel <= 5e-6, "{x:e}: {}", Num(x));
    }
}

#[test]
fn non_physical_settings_are_refused_with_the_reason() {
    let s = Settings::os4();
    let i = |id: &str| params::index_of(id.as_bytes()).unwrap();
    assert_eq!(
        params::write(&s, i("VEH_MASS"), -1.0),
        Err(Refusal::Range { lo: 0.01, hi: 100.0 })
    );
    assert!(matches!(params::write(&s, i("MOT_HUB_M"), 0.0), Err(Refusal::Mixer(_))));
    assert!(matches!(
        params::write(&s, i("CTL_ID"), 99.0),
        Err(Refusal::Controller(_))
    ));
    assert_eq!(params::write(&s, i("MOT_REV"), 1.5), Err(Refusal::NotInteger));
    let pwm = params::write(&s, i("MOT_UNIT"), 2.0).unwrap();
    assert!(matches!(
        params::write(&pwm, i("MOT_PWM_MIN"), 2100.0),
        Err(Refusal::Mixer(MixerError::PwmRange))
    ));
    // Reversing one rotor leaves a layout that still yaws (three against
    // one): accepted; reversing two neighbours makes yaw uncontrollable.
    assert!(params::write(&s, i("MOT_REV"), 1.0).is_ok());
    assert_eq!(
        params::write(&s, i("MOT_REV"), 3.0),
        Err(Refusal::Mixer(MixerError::Singular))
    );
}

#[test]
fn it_arms_only_once_aligned_and_hovers_on_the_analytic_rotor_speed() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, 1_000_000, 10);
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_TEMPORARILY_REJECTED]);
    assert!(out.texts().iter().any(|t| t.contains("aligning")), "{:?}", out.texts());
    // Every HIL_SENSOR answered by exactly one HIL_ACTUATOR_CONTROLS, all
    // zero and not armed.
    assert_eq!(out.count("HIL_ACTUATOR_CONTROLS"), 10);
    assert!(out.0.iter().all(|(_, m)| match m {
        MavMessage::HIL_ACTUATOR_CONTROLS(a) =>
            a.controls.iter().all(|&c| c == 0.0) && !a.mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
        _ => true,
    }));

    let t = rest(&mut v, &mut out, t, 2000);
    let mut out = Sent::default();
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_ACCEPTED]);
    rest(&mut v, &mut out, t, 20);
    // Hover at the armed position: each "+" rotor at √(m g / 4 kf) / Ωmax.
    let p = VehicleParams::<f64>::OS4;
    let hover = ((p.mass_kg * p.gravity_mps2 / (4.0 * p.kf_ns2)).sqrt() / p.omega_max_radps) as f32;
    let m = v.motors();
    assert!(m.iter().all(|&c| (c - hover).abs() < 0.01 * hover), "{m:?} vs {hover}");
}

#[test]
fn parameters_answer_as_the_protocol_says_and_redesigns_wait_for_disarm() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let list = MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
        target_system: 1,
        target_component: 1,
    });
    v.handle(&list, &mut out, &Still, 0).unwrap();
    assert_eq!(out.count("PARAM_VALUE"), PARAMS.len());
    // PX4's own names for the automatic modes, after the loop's.
    v.handle(&param_set("MIS_TAKEOFF_ALT", 1.5), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(out.param("MIS_TAKEOFF_ALT"), Some(1.5));
    v.handle(&param_set("MIS_TAKEOFF_ALT", -1.0), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(out.param("MIS_TAKEOFF_ALT"), Some(1.5));
    out.assert_text("MIS_TAKEOFF_ALT=-1 refused: out of [0.2, 100]");

    // Refused: the old value is echoed and a STATUSTEXT names it.
    v.handle(&param_set("VEH_MASS", -1.0), &mut out, &Still, 0).unwrap();
    assert_eq!(out.param("VEH_MASS"), Some(0.65));
    out.assert_text("VEH_MASS=-1 refused: out of [0.01, 100]");
    // Accepted, re-designed while disarmed: the core flies the new mass.
    v.handle(&param_set("VEH_MASS", 0.7), &mut out, &Still, 0).unwrap();
    assert_eq!(out.param("VEH_MASS"), Some(0.7));
    assert_eq!(v.flight_loop().vehicle().mass_kg, 0.7);
    v.handle(&param_set("CTL_ID", 0.0), &mut out, &Still, 0).unwrap();
    assert_eq!(v.flight_loop().spec(), fc_loop::FALLBACK_CONTROLLER);
    v.handle(&param_set("NO_SUCH", 1.0), &mut out, &Still, 0).unwrap();
    out.assert_text("NO_SUCH: no such parameter");

    let t = rest(&mut v, &mut out, 1_000_000, 2000);
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed());
    let mut out = Sent::default();
    v.handle(&param_set("VEH_MASS", 0.8), &mut out, &Still, 0).unwrap();
    assert_eq!(out.param("VEH_MASS"), Some(0.7));
    assert!(
        out.texts().iter().any(|t| t.ends_with("disarm first")),
        "{:?}",
        out.texts()
    );
    // Not a redesign: allowed in flight.
    v.handle(&param_set("FS_TIMEOUT_MS", 80.0), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(out.param("FS_TIMEOUT_MS"), Some(80.0));
    assert_eq!(v.flight_loop().settings().failsafe_timeout_ms, 80);
    // Disarming on the ground is obeyed; the next answer is all zeros.
    v.handle(&command(0.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(!v.armed());
    rest(&mut v, &mut out, t, 1);
    assert_eq!(v.motors(), [0.0; 4]);
}

#[test]
fn telemetry_comes_at_its_rates_and_bad_commands_are_answered_or_ignored() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, 0, 1000);
    let mut out = Sent::default();
    rest(&mut v, &mut out, t, 1000);
    // One second of simulated time.
    assert_eq!(out.count("ATTITUDE"), 50);
    assert_eq!(out.count("LOCAL_POSITION_NED"), 50);
    assert_eq!(out.count("SYS_STATUS"), 2);
    // No fence is present, and none reads as breached (MAVProxy's fence
    // module calls a clear GEOFENCE health bit a breach).
    for s in out.pick(|m| match m {
        MavMessage::SYS_STATUS(s) => Some(s.clone()),
        _ => None,
    }) {
        let fence = MavSysStatusSensor::MAV_SYS_STATUS_GEOFENCE;
        assert!(!s.onboard_control_sensors_present.contains(fence));
        assert!(s.onboard_control_sensors_health.contains(fence));
        // No battery is measured: unknown, as MAVLink spells it (UINT16_MAX
        // mV, -1 cA, -1 %), and no battery sensor present.
        assert_eq!(
            (s.voltage_battery, s.current_battery, s.battery_remaining),
            (u16::MAX, -1, -1)
        );
        let battery = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_BATTERY;
        assert!(!s.onboard_control_sensors_present.contains(battery));
    }
    assert_eq!(
        out.count("BATTERY_STATUS"),
        0,
        "no modelled battery passed off as measured"
    );
    let beats: Vec<Peer> = out
        .0
        .iter()
        .filter(|(_, m)| message_name(m) == "HEARTBEAT")
        .map(|(p, _)| *p)
        .collect();
    assert_eq!(beats, [Peer::Simulator, Peer::GroundStation]);

    let mut out = Sent::default();
    let unsupported = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        command: MavCmd::MAV_CMD_DO_SET_SERVO,
        target_system: 1,
        ..Default::default()
    });
    v.handle(&unsupported, &mut out, &Still, 0).unwrap();
    let elsewhere = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
        target_system: 7,
        ..Default::default()
    });
    v.handle(&elsewhere, &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_UNSUPPORTED]);

    // A set-point in the body frame is refused; one in LOCAL_NED is kept,
    // and flown once armed in Offboard (PX4's rule).
    let mut sp = SET_POSITION_TARGET_LOCAL_NED_DATA {
        x: 1.0,
        y: 2.0,
        z: -3.0,
        yaw: 0.5,
        target_system: 1,
        // (Default::default() would mask x: bitflags' default is its first flag.)
        type_mask: PositionTargetTypemask::empty(),
        coordinate_frame: MavFrame::MAV_FRAME_BODY_FRD,
        ..Default::default()
    };
    v.handle(
        &MavMessage::SET_POSITION_TARGET_LOCAL_NED(sp.clone()),
        &mut out,
        &Still,
        0,
    )
    .unwrap();
    assert_eq!(v.counters().setpoints_refused, 1);
    sp.coordinate_frame = MavFrame::MAV_FRAME_LOCAL_NED;
    v.handle(
        &MavMessage::SET_POSITION_TARGET_LOCAL_NED(sp.clone()),
        &mut out,
        &Still,
        0,
    )
    .unwrap();
    assert_ne!(v.setpoint().pos_ned_m, Vector3::new(1.0, 2.0, -3.0));
    v.handle(&set_mode(FlightMode::Offboard), &mut out, &Still, 0).unwrap();
    assert_eq!(v.mode(), FlightMode::Offboard);
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed());
    assert_eq!(v.setpoint().pos_ned_m, Vector3::new(1.0, 2.0, -3.0));
    assert_eq!(v.setpoint().yaw_rad, 0.5);
    // The commander holds it; the flight loop flies it from the next step
    // (the commander's part of the step hands it over), not in between.
    assert_ne!(v.flight_loop().setpoint().pos_ned_m, Vector3::new(1.0, 2.0, -3.0));
    rest(&mut v, &mut out, 2_000_000, 1);
    assert_eq!(*v.flight_loop().setpoint(), v.setpoint());
    // The stream's jerk is the slope of its acceleration over the sender's
    // clock: +0.1 m/s² in 10 ms is 10 m/s³; a steeper change is a step
    // (no jerk), as is a gap of more than 100 ms.
    for (t_ms, afx, jerk) in [(10, 0.1, 10.0), (20, 5.0, 0.0), (30, 5.2, 20.0), (300, 5.3, 0.0)] {
        let streamed = SET_POSITION_TARGET_LOCAL_NED_DATA {
            time_boot_ms: t_ms,
            afx,
            ..sp
        };
        v.handle(
            &MavMessage::SET_POSITION_TARGET_LOCAL_NED(streamed),
            &mut out,
            &Still,
            0,
        )
        .unwrap();
        let j = v.setpoint().jerk_ned_mps3;
        assert!(
            (j[0] - jerk).abs() < 1e-3 && j[1] == 0.0 && j[2] == 0.0,
            "{t_ms} ms: {j:?}"
        );
    }
    // A heading masked while armed keeps the one held.
    let masked = SET_POSITION_TARGET_LOCAL_NED_DATA {
        yaw: 2.0,
        type_mask: PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_IGNORE,
        ..sp
    };
    v.handle(&MavMessage::SET_POSITION_TARGET_LOCAL_NED(masked), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(v.setpoint().yaw_rad, 0.5);
    // A NaN velocity (not masked) is refused by the flight loop: counted,
    // said, and the set-point in force stays.
    let bad = SET_POSITION_TARGET_LOCAL_NED_DATA {
        vx: f32::NAN,
        x: 9.0,
        ..sp
    };
    v.handle(&MavMessage::SET_POSITION_TARGET_LOCAL_NED(bad), &mut out, &Still, 0)
        .unwrap();
    assert_eq!(v.counters().setpoints_refused, 2);
    assert_eq!(v.setpoint().pos_ned_m, Vector3::new(1.0, 2.0, -3.0));
    assert!(
        out.texts()
            .iter()
            .filter(|t| t.starts_with("set-point refused"))
            .count()
            == 2
    );
}

#[test]
fn losing_the_ground_station_lands_and_disarms() {
    let gcs_beat = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_GCS,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        ..Default::default()
    });
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, 1_000_000, 2000);
    v.handle(&gcs_beat, &mut out, &Still, 0).unwrap();
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed());
    // Take off (2.5 m at 0.5 m/s: 10.9 s; the samples still say "at rest":
    // the estimate stays on the ground, so it is "landed" once it lands).
    v.handle(
        &command_of(MavCmd::MAV_CMD_NAV_TAKEOFF, [f32::NAN; 7]),
        &mut out,
        &Still,
        0,
    )
    .unwrap();
    // Heard 9.9 s ago: still fine (FS_GCS_MS 10 000, PX4's COM_DL_LOSS_T).
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, t, 9_900);
    assert!(v.armed() && out.texts().is_empty(), "{:?}", out.texts());
    assert!(v.flight_loop().setpoint().pos_ned_m[2] < -0.5, "climbing");
    assert_eq!(v.mode(), FlightMode::Takeoff);
    // Silent past 10 s: land where it is, then disarm on the ground.
    rest(&mut v, &mut out, t, 200);
    let texts = out.texts();
    assert_eq!(texts, ["ground station lost: landing", "landed: disarmed"], "{texts:?}");
    assert!(!v.armed());
    // Off (FS_GCS_MS 0): never.
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let i = params::index_of(b"FS_GCS_MS").unwrap();
    v.apply(i, 0.0).unwrap();
    let t = rest(&mut v, &mut out, 1_000_000, 2000);
    v.handle(&gcs_beat, &mut out, &Still, 0).unwrap();
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    rest(&mut v, &mut out, t, 6_000);
    assert!(v.armed());
}

/// A small deterministic generator (xorshift64*).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn f32(&mut self) -> f32 {
        // Any bit pattern: NaN, ∞, subnormals, huge values.
        f32::from_bits(self.next() as u32)
    }
}

/// Frames into the flight loop: how many, from `FUZZ_FRAMES` (default
/// 10⁶, the figure in the book's MAVLink chapter).
fn fuzz_frames() -> u64 {
    std::env::var("FUZZ_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000)
}

#[test]
fn a_million_random_and_mutated_frames_never_panic_and_every_one_is_accounted_for() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut reader = MavReader::new(1);
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    // Armed and flying when the garbage starts.
    let mut out = Sent::default();
    let mut t_us = rest(&mut v, &mut out, 0, 2000);
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed());
    let (mut sent_frames, mut delivered) = (0u64, 0u64);
    let mut buf = [0u8; MAX_FRAME];
    let header = MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 0,
    };
    let frames = fuzz_frames();
    while sent_frames < frames {
        // A message of the kinds the vehicle acts on, its fields random.
        t_us += 1000;
        let msg = match rng.next() % 9 {
            0 => at_rest(t_us)[1].clone(),
            1 => MavMessage::HIL_SENSOR(HIL_SENSOR_DATA {
                time_usec: if rng.next().is_multiple_of(8) { rng.next() } else { t_us },
                xacc: rng.f32(),
                zacc: rng.f32(),
                xgyro: rng.f32(),
                fields_updated: HilSensorUpdatedFlags::from_bits_truncate(rng.next() as u32),
                ..Default::default()
            }),
            2 => MavMessage::HIL_STATE_QUATERNION(HIL_STATE_QUATERNION_DATA {
                time_usec: t_us,
                attitude_quaternion: [rng.f32(), rng.f32(), 0.0, 0.0],
                lat: rng.next() as i32,
                lon: rng.next() as i32,
                alt: rng.next() as i32,
                ..Default::default()
            }),
            3 => command(rng.f32(), rng.f32()),
            // Every command answered here and one it does not have, random
            // parameters, as COMMAND_LONG or COMMAND_INT.
            4 | 5 => {
                #[allow(deprecated)]
                const CMDS: [MavCmd; 12] = [
                    MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
                    MavCmd::MAV_CMD_NAV_TAKEOFF,
                    MavCmd::MAV_CMD_NAV_LAND,
                    MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH,
                    MavCmd::MAV_CMD_DO_SET_MODE,
                    MavCmd::MAV_CMD_REQUEST_MESSAGE,
                    MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
                    MavCmd::MAV_CMD_GET_HOME_POSITION,
                    MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                    MavCmd::MAV_CMD_MISSION_START,
                    MavCmd::MAV_CMD_DO_SET_SERVO,
                    MavCmd::MAV_CMD_DO_SET_MODE,
                ];
                let c = CMDS[(rng.next() % CMDS.len() as u64) as usize];
                // Small integers half the time (mode numbers, message ids).
                let mut p = [0.0f32; 7];
                for x in &mut p {
                    *x = if rng.next().is_multiple_of(2) {
                        (rng.next() % 256) as f32
                    } else {
                        rng.f32()
                    };
                }
                if rng.next().is_multiple_of(2) {
                    command_of(c, p)
                } else {
                    MavMessage::COMMAND_INT(COMMAND_INT_DATA {
                        param1: p[0],
                        param2: p[1],
                        param3: p[2],
                        param4: p[3],
                        x: rng.next() as i32,
                        y: rng.next() as i32,
                        z: p[6],
                        command: c,
                        target_system: 1,
                        target_component: 1,
                        ..Default::default()
                    })
                }
            }
            6 => param_set(param_id((rng.next() % PARAM_COUNT as u64) as usize), rng.f32()),
            // The mission protocol: counts (some beyond the store), items of
            // random commands, frames and coordinates, in and out of order;
            // the joystick.
            7 => match rng.next() % 4 {
                0 => mission_count((rng.next() % 24) as u16),
                3 => MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
                    x: rng.next() as i16,
                    y: rng.next() as i16,
                    z: rng.next() as i16,
                    r: rng.next() as i16,
                    buttons: rng.next() as u16,
                    target: 1,
                }),
                1 => {
                    #[allow(deprecated)]
                    const CMDS: [MavCmd; 7] = [
                        MavCmd::MAV_CMD_NAV_WAYPOINT,
                        MavCmd::MAV_CMD_NAV_TAKEOFF,
                        MavCmd::MAV_CMD_NAV_LAND,
                        MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH,
                        MavCmd::MAV_CMD_NAV_DELAY,
                        MavCmd::MAV_CMD_DO_CHANGE_SPEED,
                        MavCmd::MAV_CMD_DO_SET_SERVO,
                    ];
                    #[allow(deprecated)]
                    const FRAMES: [MavFrame; 6] = [
                        MavFrame::MAV_FRAME_GLOBAL,
                        MavFrame::MAV_FRAME_LOCAL_NED,
                        MavFrame::MAV_FRAME_MISSION,
                        MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                        MavFrame::MAV_FRAME_GLOBAL_INT,
                        MavFrame::MAV_FRAME_BODY_FRD,
                    ];
                    let frame = FRAMES[(rng.next() % FRAMES.len() as u64) as usize];
                    let c = CMDS[(rng.next() % CMDS.len() as u64) as usize];
                    let small = |r: &mut Rng| (r.next() % 8) as f32;
                    let p = [rng.f32(), small(&mut rng), rng.f32(), small(&mut rng)];
                    item(
                        (rng.next() % 18) as u16,
                        c,
                        frame,
                        p,
                        (rng.next() as i32, rng.next() as i32, rng.f32()),
                    )
                }
                _ => MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
                    seq: (rng.next() % 18) as u16,
                    target_system: 1,
                    target_component: 1,
                }),
            },
            _ => MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
                x: rng.f32(),
                y: rng.f32(),
                z: rng.f32(),
                target_system: 1,
                type_mask: PositionTargetTypemask::from_bits_truncate(rng.next() as u16),
                coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
                ..Default::default()
            }),
        };
        let n = encode(header, &msg, &mut buf).unwrap();
        // Half the frames mutated: bytes flipped, cut short, or noise before.
        let mode = rng.next() % 4;
        if mode == 1 {
            for _ in 0..1 + rng.next() % 3 {
                let i = (rng.next() % n as u64) as usize;
                buf[i] ^= 1 << (rng.next() % 8);
            }
        }
        let len = if mode == 2 { (rng.next() % n as u64) as usize } else { n };
        if mode == 3 {
            for _ in 0..rng.next() % 16 {
                if let Some(Ok((_, m))) = reader.push(rng.next() as u8) {
                    v.handle(&m, &mut out, &Still, 0).unwrap();
                    delivered += 1;
                }
            }
        }
        for &b in &buf[..len] {
            if let Some(Ok((_, m))) = reader.push(b) {
                v.handle(&m, &mut out, &Still, 0).unwrap();
                delivered += 1;
            }
        }
        out.0.clear();
        sent_frames += 1;
    }
    let c = reader.counters();
    assert_eq!(u64::from(c.ok), delivered);
    // A quarter of the frames are cut short, and each swallows the start
    // of the next; a flipped bit is (almost always) a bad CRC. Still, the
    // vehicle itself must have been fed plenty, of every kind.
    assert!(delivered > frames / 4, "{c:?}");
    let vc = v.counters();
    assert!(
        vc.steps > 0 && vc.sensors_refused > 0 && vc.params_refused > 0,
        "{vc:?}"
    );
    assert!(
        vc.states_refused > 0 && vc.setpoints_refused > 0 && vc.commands_refused > 0,
        "{vc:?}"
    );
    assert!(c.bad_crc > 0 && c.skipped_bytes > 0, "{c:?}");
    // The vehicle still flies: it answers a good sample (fixed memory: no
    // state grows with what it was fed).
    let mut out = Sent::default();
    v.handle(&at_rest(u64::MAX / 2)[1], &mut out, &Still, 0).unwrap();
    assert_eq!(out.count("HIL_ACTUATOR_CONTROLS"), 1);
    std::println!("fuzz: {frames} frames, reader {c:?}, vehicle {:?}", v.counters());
}

/// A vehicle aligned at rest at home (2 s of samples and fixes), then 10 s
/// of `HIL_SENSOR` only at 1 kHz: the at-rest sample as `edit` changes it;
/// `each(k, vehicle)` sees the vehicle before sample `k`.
fn sensors_only(edit: impl Fn(&mut HIL_SENSOR_DATA), mut each: impl FnMut(u64, &MavVehicle)) -> MavVehicle {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, 0, 2_000);
    let [_, MavMessage::HIL_SENSOR(mut m)] = at_rest(0) else {
        unreachable!()
    };
    edit(&mut m);
    for k in 0..10_000 {
        each(k, &v);
        m.time_usec = t + k * 1_000;
        v.handle(&MavMessage::HIL_SENSOR(m.clone()), &mut out, &Still, 0)
            .unwrap();
    }
    v
}

/// A barometer flagged in `HIL_SENSOR` bounds the height when nothing else
/// does. Aligned at rest at home with fixes, then 10 s of `HIL_SENSOR`
/// only, its accelerometer reading 0.1 m/s² too much upward force (a bias
/// the filter has not seen): dead reckoning climbs ½·0.1·10² = 5 m; with a
/// barometer that reads the same pressure altitude throughout (the vehicle
/// has not moved) the estimate stays within 20 cm of the ground, and has
/// stopped moving by the end (the filter learns the bias slowly: its prior
/// on it has shrunk during the rest).
#[test]
fn a_flagged_barometer_bounds_the_height_without_position_fixes() {
    let drift = |baro: bool| {
        let z = |v: &MavVehicle| {
            v.flight_loop()
                .navigator()
                .estimate()
                .map_or(f32::NAN, |e| e.pos_ned_m[2])
        };
        let mut z_7s = f32::NAN;
        let v = sensors_only(
            |m| {
                m.zacc = -9.81 - 0.1;
                if baro {
                    m.pressure_alt = 480.0;
                    m.fields_updated |= HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_PRESSURE_ALT;
                }
            },
            |k, v| {
                if k == 7_000 {
                    z_7s = z(v);
                }
            },
        );
        (z_7s, z(&v), v.counters().baro_fixes)
    };
    let (_, dead_reckoned, none) = drift(false);
    let (at_7s, with_baro, fused) = drift(true);
    assert_eq!(none, 0);
    // 50 Hz for 10 s.
    assert!((499..=501).contains(&fused), "{fused}");
    assert!(
        (dead_reckoned + 5.0).abs() < 0.1,
        "dead reckoning climbs ½·0.1·10² m: z {dead_reckoned}"
    );
    assert!(with_baro.abs() < 0.2, "with the barometer: z {with_baro}");
    assert!((with_baro - at_7s).abs() < 0.03, "still moving: {at_7s} → {with_baro}");
}

/// A magnetometer flagged in `HIL_SENSOR` holds the heading when nothing
/// else does: 10 s without fixes, the gyro reading 0.02 rad/s about z too
/// much (a bias the filter has not seen). Dead reckoning turns by 0.2 rad;
/// with the magnetometer reading the field of the heading it never left,
/// the heading stays within 2°.
#[test]
fn a_flagged_magnetometer_holds_the_heading_without_fixes() {
    let heading = |mag: bool| {
        let v = sensors_only(
            |m| {
                m.zgyro = 0.02;
                if mag {
                    // North and down, as in central Europe (gauss).
                    (m.xmag, m.ymag, m.zmag) = (0.21, 0.0, 0.43);
                    m.fields_updated |= HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XMAG
                        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YMAG
                        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZMAG;
                }
            },
            |_, _| {},
        );
        let psi = v
            .flight_loop()
            .navigator()
            .estimate()
            .map_or(f32::NAN, |e| e.euler()[2]);
        (psi, v.counters().mag_fixes)
    };
    let (dead_reckoned, none) = heading(false);
    let (with_mag, fused) = heading(true);
    assert_eq!(none, 0);
    assert!((499..=501).contains(&fused), "{fused}");
    assert!(
        (dead_reckoned - 0.2).abs() < 0.01,
        "dead reckoning turns 0.02·10 rad: ψ {dead_reckoned}"
    );
    assert!(with_mag.abs() < 0.035, "with the magnetometer: ψ {with_mag}");
}

/// What MAVSDK, MAVProxy and QGroundControl read at connection and send to
/// fly, answered as PX4 answers: a PX4 heartbeat and its mode encoding,
/// AUTOPILOT_VERSION on request, streams at the rates asked for, the modes
/// with PX4's rules (takeoff only armed, offboard only while set-points
/// stream, lost set-points end in Hold), every other command UNSUPPORTED.
#[test]
fn px4s_tools_find_a_px4_autopilot_with_its_modes_commands_and_streams() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, 1_000_000, 2000);
    let last = |out: &Sent, name: &str| {
        out.0
            .iter()
            .rev()
            .find(|(_, m)| message_name(m) == name)
            .map(|(_, m)| m.clone())
            .unwrap_or_else(|| panic!("no {name}"))
    };
    let MavMessage::HEARTBEAT(hb) = last(&out, "HEARTBEAT") else {
        unreachable!()
    };
    assert_eq!(hb.autopilot, MavAutopilot::MAV_AUTOPILOT_PX4);
    assert_eq!(hb.custom_mode, 0x0003_0000, "Position (POSCTL) on the ground");
    assert!(hb.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED));

    // AUTOPILOT_VERSION on REQUEST_MESSAGE (as COMMAND_INT too) and on the older request.
    let mut out = Sent::default();
    let req = MavMessage::COMMAND_INT(COMMAND_INT_DATA {
        param1: 148.0,
        command: MavCmd::MAV_CMD_REQUEST_MESSAGE,
        target_system: 1,
        target_component: 1,
        ..Default::default()
    });
    v.handle(&req, &mut out, &Still, 0).unwrap();
    #[allow(deprecated)]
    let caps = command_of(
        MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    );
    v.handle(&caps, &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_ACCEPTED; 2]);
    assert_eq!(out.count("AUTOPILOT_VERSION"), 2);
    let MavMessage::AUTOPILOT_VERSION(av) = last(&out, "AUTOPILOT_VERSION") else {
        unreachable!()
    };
    use MavProtocolCapability as C;
    assert!(av.capabilities.contains(
        C::MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | C::MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | C::MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    ));
    assert!(av.capabilities.contains(C::MAV_PROTOCOL_CAPABILITY_MISSION_INT));
    assert!(!av
        .capabilities
        .intersects(C::MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | C::MAV_PROTOCOL_CAPABILITY_FTP));
    // Home and the landed state on request; the battery (147), which the
    // vehicle does not measure, and an unknown message are UNSUPPORTED.
    let mut out = Sent::default();
    for id in [242.0, 245.0, 33.0, 230.0, 147.0, 9999.0] {
        v.handle(
            &command_of(MavCmd::MAV_CMD_REQUEST_MESSAGE, [id, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            &mut out,
            &Still,
            0,
        )
        .unwrap();
    }
    let ok = MavResult::MAV_RESULT_ACCEPTED;
    let unsupported = MavResult::MAV_RESULT_UNSUPPORTED;
    assert_eq!(out.acks(), [ok, ok, ok, ok, unsupported, unsupported]);
    let MavMessage::ESTIMATOR_STATUS(es) = last(&out, "ESTIMATOR_STATUS") else {
        unreachable!()
    };
    use EstimatorStatusFlags as F;
    assert!(es
        .flags
        .contains(F::ESTIMATOR_ATTITUDE | F::ESTIMATOR_POS_HORIZ_REL | F::ESTIMATOR_POS_HORIZ_ABS));
    assert!(es.pos_horiz_accuracy > 0.0 && es.pos_horiz_accuracy < 0.05, "{es:?}");
    // At rest on consistent fixes: every test ratio inside the gate.
    for r in [es.pos_horiz_ratio, es.pos_vert_ratio, es.vel_ratio, es.mag_ratio] {
        assert!((0.0..1.0).contains(&r), "{es:?}");
    }
    let MavMessage::HOME_POSITION(h) = last(&out, "HOME_POSITION") else {
        unreachable!()
    };
    assert_eq!(
        (h.latitude, h.longitude, h.altitude),
        (474_000_000, 85_000_000, 500_000)
    );
    let MavMessage::EXTENDED_SYS_STATE(x) = last(&out, "EXTENDED_SYS_STATE") else {
        unreachable!()
    };
    assert_eq!(x.landed_state, MavLandedState::MAV_LANDED_STATE_ON_GROUND);
    // No battery is measured, so none is reported (SYS_STATUS's side:
    // `telemetry_comes_at_its_rates…`).
    assert!(out.0.iter().all(|m| !matches!(m.1, MavMessage::BATTERY_STATUS(_))));
    let MavMessage::GLOBAL_POSITION_INT(g) = last(&out, "GLOBAL_POSITION_INT") else {
        unreachable!()
    };
    assert!((g.lat - 474_000_000).abs() <= 1 && g.relative_alt.abs() < 10, "{g:?}");

    // Streams at the rate asked for: GLOBAL_POSITION_INT at 50 Hz, then off.
    let interval =
        |id: f32, us: f32| command_of(MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL, [id, us, 0.0, 0.0, 0.0, 0.0, 0.0]);
    v.handle(&interval(33.0, 20_000.0), &mut out, &Still, 0).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, t, 1000);
    assert_eq!(out.count("GLOBAL_POSITION_INT"), 50);
    assert_eq!(out.count("EXTENDED_SYS_STATE"), 5);
    v.handle(&interval(33.0, -1.0), &mut out, &Still, 0).unwrap();
    v.handle(&interval(12345.0, 1000.0), &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [ok, MavResult::MAV_RESULT_UNSUPPORTED]);
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, t, 1000);
    assert_eq!(out.count("GLOBAL_POSITION_INT"), 0);

    // Refusals by PX4's rules, each said; commands it does not have: UNSUPPORTED.
    let mut out = Sent::default();
    for m in [FlightMode::Offboard, FlightMode::Takeoff, FlightMode::Mission] {
        v.handle(&set_mode(m), &mut out, &Still, 0).unwrap();
    }
    v.handle(&command_of(MavCmd::MAV_CMD_DO_SET_SERVO, [0.0; 7]), &mut out, &Still, 0)
        .unwrap();
    let denied = MavResult::MAV_RESULT_DENIED;
    assert_eq!(out.acks(), [denied, denied, denied, MavResult::MAV_RESULT_UNSUPPORTED]);
    assert_eq!(
        out.texts(),
        [
            "Offboard refused: no set-points streaming",
            "Takeoff refused: disarmed",
            "Mission refused: no mission"
        ]
    );
    assert_eq!(v.mode(), FlightMode::Position);

    // A base mode alone, read as PX4's commander reads it (MAVProxy's
    // `mode 4`): AUTO is the mission (none yet: refused), manual input
    // without GUIDED is not flown, GUIDED with manual input is Position.
    let mut out = Sent::default();
    v.handle(&set_mode(FlightMode::Hold), &mut out, &Still, 0).unwrap();
    for base in [4.0, 64.0, 72.0] {
        let c = command_of(MavCmd::MAV_CMD_DO_SET_MODE, [base, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        v.handle(&c, &mut out, &Still, 0).unwrap();
    }
    assert_eq!(out.acks(), [ok, denied, denied, ok]);
    assert_eq!(
        out.texts(),
        ["Mission refused: no mission", "base mode 64 not flown here"]
    );
    assert_eq!(v.mode(), FlightMode::Position);

    // SET_MODE (id 11), which ground stations still send: PX4 turns it into
    // DO_SET_MODE and acknowledges that command.
    let mut out = Sent::default();
    let (main, sub) = FlightMode::Hold.px4();
    #[allow(deprecated)]
    let set = MavMessage::SET_MODE(SET_MODE_DATA {
        custom_mode: (u32::from(main) << 16) | (u32::from(sub) << 24),
        target_system: 1,
        base_mode: MavModeFlag::from_bits_truncate(1),
    });
    v.handle(&set, &mut out, &Still, 0).unwrap();
    assert_eq!(v.mode(), FlightMode::Hold);
    assert!(matches!(
        &out.0[..],
        [(_, MavMessage::COMMAND_ACK(a))] if a.command == MavCmd::MAV_CMD_DO_SET_MODE && a.result == ok
    ));
    v.handle(&set_mode(FlightMode::Position), &mut out, &Still, 0).unwrap();
    assert_eq!(v.mode(), FlightMode::Position);

    // Hold, arm, take off to MIS_TAKEOFF_ALT: Takeoff, then Hold at 1.5 m.
    let mut out = Sent::default();
    v.handle(&set_mode(FlightMode::Hold), &mut out, &Still, 0).unwrap();
    v.handle(&param_set("MIS_TAKEOFF_ALT", 1.5), &mut out, &Still, 0)
        .unwrap();
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    v.handle(
        &command_of(MavCmd::MAV_CMD_NAV_TAKEOFF, [f32::NAN; 7]),
        &mut out,
        &Still,
        0,
    )
    .unwrap();
    assert_eq!(out.acks(), [ok; 3]);
    assert_eq!(v.mode(), FlightMode::Takeoff);
    assert_eq!(v.landed_state(), MavLandedState::MAV_LANDED_STATE_TAKEOFF);
    // 1.5 m at 0.5 m/s: 6.6 s; the heartbeat after says Hold.
    let t = rest(&mut v, &mut out, t, 8_000);
    assert_eq!(v.mode(), FlightMode::Hold);
    assert!((v.flight_loop().setpoint().pos_ned_m[2] + 1.5).abs() < 1e-4);
    out.assert_text("takeoff done: hold");
    let MavMessage::HEARTBEAT(hb) = last(&out, "HEARTBEAT") else {
        unreachable!()
    };
    assert_eq!(hb.custom_mode, FlightMode::Hold.custom_mode());
    // A takeoff to 10²⁰ m above sea level cannot be planned: refused, still Hold.
    let mut out = Sent::default();
    let absurd = command_of(MavCmd::MAV_CMD_NAV_TAKEOFF, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e20]);
    v.handle(&absurd, &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [denied]);
    out.assert_text("Takeoff refused: goal out of range");
    assert_eq!(v.mode(), FlightMode::Hold);

    // Offboard while set-points stream; they stop: Hold after COM_OF_LOSS_T (1 s).
    let target = MavMessage::SET_POSITION_TARGET_LOCAL_NED(SET_POSITION_TARGET_LOCAL_NED_DATA {
        x: 2.0,
        z: -1.5,
        target_system: 1,
        type_mask: PositionTargetTypemask::empty(),
        coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
        ..Default::default()
    });
    let mut out = Sent::default();
    v.handle(&target, &mut out, &Still, 0).unwrap();
    v.handle(&set_mode(FlightMode::Offboard), &mut out, &Still, 0).unwrap();
    assert_eq!((v.mode(), v.setpoint().pos_ned_m[0]), (FlightMode::Offboard, 2.0));
    let t = rest(&mut v, &mut out, t, 1_100);
    assert_eq!(v.mode(), FlightMode::Hold);
    out.assert_text("offboard set-points lost: hold");

    // Return: up to RTL_RETURN_ALT (2 m) over where it is, home, down; on
    // the ground it disarms (the samples say it never left).
    let mut out = Sent::default();
    v.handle(
        &command_of(MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH, [0.0; 7]),
        &mut out,
        &Still,
        0,
    )
    .unwrap();
    assert_eq!(v.mode(), FlightMode::Return);
    let mut highest: f32 = 0.0;
    let mut t = t;
    while v.armed() && t < 60_000_000 {
        t = rest(&mut v, &mut out, t, 100);
        highest = highest.min(v.flight_loop().setpoint().pos_ned_m[2]);
    }
    assert!(!v.armed(), "landed and disarmed");
    assert!((highest + 2.0).abs() < 1e-3, "{highest}");
    let sp = v.flight_loop().setpoint().pos_ned_m;
    assert!(sp[0].abs() < 1e-3 && sp[1].abs() < 1e-3, "over home: {sp:?}");
    out.assert_text("landed: disarmed");
}

/// A mission item for the tests: `command` in `frame` at (x, y, z).
fn item(seq: u16, command: MavCmd, frame: MavFrame, params: [f32; 4], xyz: (i32, i32, f32)) -> MavMessage {
    MavMessage::MISSION_ITEM_INT(MISSION_ITEM_INT_DATA {
        param1: params[0],
        param2: params[1],
        param3: params[2],
        param4: params[3],
        x: xyz.0,
        y: xyz.1,
        z: xyz.2,
        seq,
        command,
        target_system: 1,
        target_component: 1,
        frame,
        current: 0,
        autocontinue: 1,
    })
}

/// `MISSION_REQUEST_LIST` for this vehicle (a download's start).
fn mission_request_list() -> MavMessage {
    MavMessage::MISSION_REQUEST_LIST(MISSION_REQUEST_LIST_DATA {
        target_system: 1,
        target_component: 1,
    })
}

fn mission_count(count: u16) -> MavMessage {
    MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
        count,
        target_system: 1,
        target_component: 1,
    })
}

impl Sent {
    fn mission_acks(&self) -> Vec<MavMissionResult> {
        self.pick(|m| match m {
            MavMessage::MISSION_ACK(a) => Some(a.mavtype),
            _ => None,
        })
    }
    fn requests(&self) -> Vec<u16> {
        self.pick(|m| match m {
            MavMessage::MISSION_REQUEST_INT(r) => Some(r.seq),
            _ => None,
        })
    }
    fn reached(&self) -> Vec<u16> {
        self.pick(|m| match m {
            MavMessage::MISSION_ITEM_REACHED(r) => Some(r.seq),
            _ => None,
        })
    }
}

/// The mission protocol as the MAVLink specification draws it: an upload
/// item by item on the vehicle's requests, acknowledged; a download that
/// gives the same items back; the store's capacity, an item it cannot fly,
/// a ground station that stops answering, a clear. Then the mission flown
/// item by item (the samples say it stays at home, so the waypoint is
/// there): reached and current reported, a hold, a speed change, a delay,
/// and a return that hands over to Return.
#[test]
fn missions_upload_download_and_fly_item_by_item() {
    use MavCmd as C;
    let (rel, local, mis) = (
        #[allow(deprecated)]
        MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
        MavFrame::MAV_FRAME_LOCAL_NED,
        MavFrame::MAV_FRAME_MISSION,
    );
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let t = rest(&mut v, &mut out, 1_000_000, 2000);
    let items = [
        item(
            0,
            C::MAV_CMD_NAV_WAYPOINT,
            rel,
            [1.0, 0.05, 0.0, 0.0],
            (474_000_000, 85_000_000, 0.0),
        ),
        item(1, C::MAV_CMD_DO_CHANGE_SPEED, mis, [1.0, 0.5, -1.0, 0.0], (0, 0, 0.0)),
        item(2, C::MAV_CMD_NAV_DELAY, mis, [0.5, 0.0, 0.0, 0.0], (0, 0, 0.0)),
        item(3, C::MAV_CMD_NAV_RETURN_TO_LAUNCH, mis, [0.0; 4], (0, 0, 0.0)),
    ];
    let mut out = Sent::default();
    v.handle(&mission_count(4), &mut out, &Still, 0).unwrap();
    for it in &items {
        v.handle(it, &mut out, &Still, 0).unwrap();
    }
    assert_eq!(out.requests(), [0, 1, 2, 3]);
    assert_eq!(out.mission_acks(), [MavMissionResult::MAV_MISSION_ACCEPTED]);
    // Downloaded as uploaded.
    let mut out = Sent::default();
    v.handle(&mission_request_list(), &mut out, &Still, 0).unwrap();
    let MavMessage::MISSION_COUNT(c) = &out.0[0].1 else {
        panic!("{:?}", out.0)
    };
    assert_eq!(c.count, 4);
    let ask = |seq| {
        MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
            seq,
            target_system: 1,
            target_component: 1,
        })
    };
    v.handle(&ask(2), &mut out, &Still, 0).unwrap();
    let MavMessage::MISSION_ITEM_INT(back) = &out.0[1].1 else {
        panic!()
    };
    let MavMessage::MISSION_ITEM_INT(sent) = &items[2] else {
        unreachable!()
    };
    assert_eq!((back.seq, back.command, back.param1), (2, sent.command, sent.param1));
    v.handle(&ask(9), &mut out, &Still, 0).unwrap();
    assert_eq!(out.mission_acks(), [MavMissionResult::MAV_MISSION_INVALID_SEQUENCE]);

    // 17 items do not fit; an item it cannot fly ends the upload, empty.
    let mut other = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut o = Sent::default();
    rest(&mut other, &mut o, 1_000_000, 10);
    let mut o = Sent::default();
    other.handle(&mission_count(17), &mut o, &Still, 0).unwrap();
    other.handle(&mission_count(2), &mut o, &Still, 0).unwrap();
    other
        .handle(
            &item(0, C::MAV_CMD_DO_SET_SERVO, mis, [0.0; 4], (0, 0, 0.0)),
            &mut o,
            &Still,
            0,
        )
        .unwrap();
    other.handle(&mission_count(1), &mut o, &Still, 0).unwrap();
    other
        .handle(
            &item(0, C::MAV_CMD_NAV_WAYPOINT, local, [0.0; 4], (50_000_000, 0, -1.0)),
            &mut o,
            &Still,
            0,
        )
        .unwrap();
    assert_eq!(
        o.mission_acks(),
        [
            MavMissionResult::MAV_MISSION_NO_SPACE,
            MavMissionResult::MAV_MISSION_UNSUPPORTED,
            MavMissionResult::MAV_MISSION_UNSUPPORTED_FRAME, // 5 km away: out of the planner's reach
        ]
    );
    // A ground station that stops answering: asked 20 more times, 0.25 s
    // apart (PX4's), then cancelled.
    let mut o = Sent::default();
    other.handle(&mission_count(3), &mut o, &Still, 0).unwrap();
    rest(&mut other, &mut o, 1_010_000, 5_500);
    assert_eq!(o.requests(), [0; 21]);
    assert_eq!(o.mission_acks(), [MavMissionResult::MAV_MISSION_OPERATION_CANCELLED]);

    // Flown: Mission needs the vehicle armed.
    let mut out = Sent::default();
    v.handle(&set_mode(FlightMode::Mission), &mut out, &Still, 0).unwrap();
    out.assert_text("Mission refused: disarmed");
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    v.handle(&set_mode(FlightMode::Mission), &mut out, &Still, 0).unwrap();
    assert_eq!(v.mode(), FlightMode::Mission);
    // The waypoint (home: a 0.5 s leg), held 1 s; the speed; the 0.5 s
    // delay; the return.
    let t = rest(&mut v, &mut out, t, 1_200);
    assert_eq!(out.reached(), Vec::<u16>::new(), "still holding at the waypoint");
    let t = rest(&mut v, &mut out, t, 400);
    assert_eq!(out.reached(), [0, 1]);
    rest(&mut v, &mut out, t, 600);
    assert_eq!(out.reached(), [0, 1, 2, 3]);
    assert_eq!(v.mode(), FlightMode::Return);
    // MISSION_CURRENT followed each item.
    let currents = out.pick(|m| match m {
        MavMessage::MISSION_CURRENT(c) => Some(c.seq),
        _ => None,
    });
    assert!(currents.windows(4).any(|w| w == [1, 2, 3, 4]), "{currents:?}");
    // A clear while flying it: the mission is left for Hold first.
    let mut out = Sent::default();
    v.handle(&set_mode(FlightMode::Mission), &mut out, &Still, 0).unwrap();
    v.handle(
        &MavMessage::MISSION_CLEAR_ALL(MISSION_CLEAR_ALL_DATA {
            target_system: 1,
            target_component: 1,
        }),
        &mut out,
        &Still,
        0,
    )
    .unwrap();
    assert_eq!(out.mission_acks(), [MavMissionResult::MAV_MISSION_ACCEPTED]);
    assert_eq!(v.mode(), FlightMode::Hold);
}

/// `MANUAL_CONTROL` in Position mode moves the set-point at the joystick's
/// velocity (full forward: `MPC_VEL_MANUAL`, 1 m/s, heading north: north);
/// throttle down on the ground does not push it below the ground; a
/// joystick that falls silent for `COM_RC_LOSS_T` (0.5 s) is lost: Land.
#[test]
fn a_joystick_moves_the_setpoint_in_position_mode_and_its_loss_lands() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let mut t = rest(&mut v, &mut out, 1_000_000, 2000);
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert_eq!((v.armed(), v.mode()), (true, FlightMode::Position));
    let stick = |x: i16, z: i16| {
        MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
            x,
            y: 0,
            z,
            r: 0,
            buttons: 0,
            target: 1,
        })
    };
    // Throttle full down on the ground: stays on the ground.
    for _ in 0..20 {
        v.handle(&stick(0, 0), &mut out, &Still, 0).unwrap();
        t = rest(&mut v, &mut out, t, 50);
    }
    assert!(v.flight_loop().setpoint().pos_ned_m[2] <= 1e-3 && v.flight_loop().setpoint().pos_ned_m[2] > -1e-3);
    // Full forward, centred throttle, 20 Hz for 1 s: 1 m north at 1 m/s.
    let north0 = v.flight_loop().setpoint().pos_ned_m[0];
    for _ in 0..20 {
        v.handle(&stick(1000, 500), &mut out, &Still, 0).unwrap();
        t = rest(&mut v, &mut out, t, 50);
    }
    let sp = *v.flight_loop().setpoint();
    assert!((sp.pos_ned_m[0] - north0 - 1.0).abs() < 0.01, "{sp:?}");
    assert!((sp.vel_ned_mps[0] - 1.0).abs() < 1e-6 && sp.pos_ned_m[1].abs() < 1e-6);
    // Silent: lost after 0.5 s, Land (here on the ground: landed at once).
    let mut out = Sent::default();
    rest(&mut v, &mut out, t, 700);
    let texts = out.texts();
    assert_eq!(texts, ["joystick lost: landing", "landed: disarmed"], "{texts:?}");
    assert!(!v.armed());
}

/// What QGroundControl asks at connection (its `InitialConnectStateMachine`:
/// AUTOPILOT_VERSION by REQUEST_MESSAGE, component information and the
/// standard modes by REQUEST_MESSAGE, the whole parameter list, the mission
/// download; geofence and rally only when the capabilities claim them),
/// then home, replayed and answered: each request acknowledged, what the
/// vehicle has given, what it has not `UNSUPPORTED` (QGroundControl then
/// falls back to its PX4 plugin's tables), no fence or rally claimed.
#[test]
fn what_qgroundcontrol_asks_at_connection_is_answered() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    rest(&mut v, &mut out, 1_000_000, 2000);
    let request = |id: f32| command_of(MavCmd::MAV_CMD_REQUEST_MESSAGE, [id, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let mut out = Sent::default();
    // AUTOPILOT_VERSION (148), COMPONENT_METADATA (397), AVAILABLE_MODES (435).
    for id in [148.0, 397.0, 435.0] {
        v.handle(&request(id), &mut out, &Still, 0).unwrap();
    }
    let unsupported = MavResult::MAV_RESULT_UNSUPPORTED;
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_ACCEPTED, unsupported, unsupported]);
    let Some(MavMessage::AUTOPILOT_VERSION(av)) = out
        .0
        .iter()
        .map(|(_, m)| m.clone())
        .find(|m| message_name(m) == "AUTOPILOT_VERSION")
    else {
        panic!("no AUTOPILOT_VERSION")
    };
    use MavProtocolCapability as C;
    assert!(!av
        .capabilities
        .intersects(C::MAV_PROTOCOL_CAPABILITY_MISSION_FENCE | C::MAV_PROTOCOL_CAPABILITY_MISSION_RALLY));
    // QGroundControl reads flight_sw_version's bytes as major.minor.patch.type.
    assert_eq!(av.flight_sw_version.to_be_bytes(), [0, 1, 0, 255]);
    // The parameter load: every index once, each with the total.
    let mut out = Sent::default();
    v.handle(
        &MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        }),
        &mut out,
        &Still,
        0,
    )
    .unwrap();
    let mut indices = out.pick(|m| match m {
        MavMessage::PARAM_VALUE(p) if usize::from(p.param_count) == PARAM_COUNT => Some(p.param_index),
        _ => None,
    });
    indices.sort_unstable();
    assert_eq!(indices, (0..PARAM_COUNT as u16).collect::<Vec<_>>());
    // The mission download: an empty store, counted.
    let mut out = Sent::default();
    v.handle(&mission_request_list(), &mut out, &Still, 0).unwrap();
    assert!(
        matches!(
            &out.0[..],
            [(_, MavMessage::MISSION_COUNT(MISSION_COUNT_DATA { count: 0, .. }))]
        ),
        "{:?}",
        out.0
    );
    // Home, by the older request QGroundControl also sends.
    let mut out = Sent::default();
    #[allow(deprecated)]
    let home = command_of(MavCmd::MAV_CMD_GET_HOME_POSITION, [0.0; 7]);
    v.handle(&home, &mut out, &Still, 0).unwrap();
    assert_eq!(out.acks(), [MavResult::MAV_RESULT_ACCEPTED]);
    assert_eq!(out.count("HOME_POSITION"), 1);
}

/// The jerk taken from a streamed figure-8 (A = 1 m, a 6 s lap, sent every
/// 10 ms) is the analytic one, `(−Aω³ cos ωt, −4Aω³ cos 2ωt)`, to the
/// slope's own error (half a period of the snap: under 0.05 m/s³).
#[test]
fn the_jerk_of_a_streamed_eight_is_its_analytic_jerk() {
    use super::streamed_jerk;
    let w = 2.0 * core::f32::consts::PI / 6.0;
    let acc = |t: f32| Vector3::new(-w * w * libm::sinf(w * t), -2.0 * w * w * libm::sinf(2.0 * w * t), 0.0);
    let mut last = None;
    for k in 0..600u32 {
        let t = k as f32 * 0.01;
        let j = streamed_jerk(last, acc(t), k * 10);
        if k > 0 {
            // The slope is the jerk half a period back.
            let tm = t - 0.005;
            let want = Vector3::new(
                -w.powi(3) * libm::cosf(w * tm),
                -4.0 * w.powi(3) * libm::cosf(2.0 * w * tm),
                0.0,
            );
            assert!((j - want).amax() < 0.05, "{t} s: {j:?} vs {want:?}");
        } else {
            assert_eq!(j, Vector3::zeros(), "no jerk from one sample");
        }
        last = Some((acc(t), k * 10));
    }
}

/// A sink whose link signs (the host's and the image's are alike).
#[derive(Default)]
struct SignedSink {
    sent: Sent,
    signing: crate::signing::Signing,
}

impl MavSink for SignedSink {
    type Error = Infallible;
    fn send(&mut self, to: Peer, msg: &MavMessage) -> Result<(), Infallible> {
        self.sent.send(to, msg)
    }
    fn signing(&mut self) -> Option<&mut crate::signing::Signing> {
        Some(&mut self.signing)
    }
}

/// What a fuzzed frame was, to know what the vehicle may act on.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kind {
    /// Signed with the key the vehicle holds, newer than the stream's last.
    Owner,
    /// Unsigned.
    Unsigned,
    /// Signed with another key.
    Forged,
    /// An owner's frame sent again.
    Replayed,
}

#[test]
fn signed_forged_replayed_frames_and_setup_signing_in_every_state() {
    use crate::encode_signed;
    use crate::signing::{Key, Signing};
    let frames: u64 = fuzz_frames();
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut reader = MavReader::new(1);
    let mut rng = Rng(0x2545_f491_4f6c_dd1d);
    let mut sink = SignedSink::default();
    let mut t_us = rest(&mut v, &mut sink.sent, 0, 2000);
    // The owner provisions a key (unsigned: none is set) and signs from then on.
    let mut key: Key = [0x5a; 32];
    let mut owner = Signing::with_key(key, 1_000);
    let mut forger = Signing::with_key([0xa5; 32], 1_000_000_000);
    let header = |sys| MavHeader {
        system_id: sys,
        component_id: 190,
        sequence: 0,
    };
    let mut buf = [0u8; MAX_FRAME];
    let setup = |k: Key, ts: u64| {
        MavMessage::SETUP_SIGNING(SETUP_SIGNING_DATA {
            target_system: 1,
            target_component: 1,
            secret_key: k,
            initial_timestamp: ts,
        })
    };
    let n = encode(header(255), &setup(key, 1_000), &mut buf).unwrap();
    for &b in &buf[..n] {
        if let Some(Ok((_, m))) = reader.push_signed(b, &mut sink.signing) {
            v.handle(&m, &mut sink, &Still, 0).unwrap();
        }
    }
    assert!(sink.signing.is_on());
    let mut last_owner = Vec::new();
    let (mut delivered, mut by_kind) = (0u64, [0u64; 4]);
    for _ in 0..frames {
        t_us += 1000;
        let msg = match rng.next() % 6 {
            0 => at_rest(t_us)[1].clone(),
            1 => command(if rng.next().is_multiple_of(2) { 1.0 } else { 0.0 }, FORCE),
            2 => param_set(param_id((rng.next() % PARAM_COUNT as u64) as usize), rng.f32()),
            3 => mission_count((rng.next() % 4) as u16),
            // A key change: a new key, the same, or a blank (clear) one.
            4 => {
                let k = match rng.next() % 3 {
                    0 => [rng.next() as u8 & 0x7f; 32], // never the forger's (0xa5)
                    1 => key,
                    _ => [0; 32],
                };
                setup(k, rng.next() % 3 * 500)
            }
            _ => command_of(MavCmd::MAV_CMD_NAV_TAKEOFF, [0.0; 7]),
        };
        let kind = match rng.next() % 4 {
            0 => Kind::Owner,
            1 => Kind::Unsigned,
            2 => Kind::Forged,
            _ => Kind::Replayed,
        };
        let frame: Vec<u8> = match kind {
            Kind::Owner => {
                let n = encode_signed(header(255), &msg, &mut buf, &mut owner).unwrap();
                last_owner = buf[..n].to_vec();
                last_owner.clone()
            }
            Kind::Unsigned => {
                let n = encode(header(66), &msg, &mut buf).unwrap();
                buf[..n].to_vec()
            }
            Kind::Forged => {
                let n = encode_signed(header(66), &msg, &mut buf, &mut forger).unwrap();
                buf[..n].to_vec()
            }
            Kind::Replayed => last_owner.clone(),
        };
        let (armed_before, key_before) = (v.armed(), sink.signing.key().copied());
        for &b in &frame {
            if let Some(r) = reader.push_signed(b, &mut sink.signing) {
                if let Ok((_, m)) = r {
                    // Only the owner's fresh frames get through while a key is set.
                    assert!(key_before.is_none() || kind == Kind::Owner, "{kind:?} delivered: {m:?}");
                    delivered += 1;
                    by_kind[kind as usize] += 1;
                    v.handle(&m, &mut sink, &Still, 0).unwrap();
                } else {
                    assert!(
                        kind != Kind::Owner || key_before.is_none() || key_before != Some(key),
                        "{r:?}"
                    );
                }
            }
        }
        // Arming and the key change only by a frame the vehicle accepted.
        if key_before.is_some() && kind != Kind::Owner {
            assert_eq!((v.armed(), sink.signing.key().copied()), (armed_before, key_before));
        }
        // The owner follows what the vehicle now holds (its SETUP_SIGNING
        // was accepted or refused; the vehicle's state says which).
        match sink.signing.key() {
            Some(k) if *k != key => {
                key = *k;
                owner = Signing::with_key(key, owner.timestamp());
            }
            None => {
                // Signing cleared: provision again (unsigned, disarmed first).
                let n = encode(header(255), &command(0.0, FORCE), &mut buf).unwrap();
                let n2 = encode(header(255), &setup(key, owner.timestamp()), &mut buf[n..]).unwrap();
                for &b in &buf[..n + n2] {
                    if let Some(Ok((_, m))) = reader.push_signed(b, &mut sink.signing) {
                        v.handle(&m, &mut sink, &Still, 0).unwrap();
                    }
                }
                if sink.signing.key() != Some(&key) {
                    // Still armed (in the air): wait for the owner's next frames.
                    continue;
                }
                owner = Signing::with_key(key, owner.timestamp());
            }
            _ => {}
        }
        sink.sent.0.clear();
    }
    let s = sink.signing.counters();
    assert!(by_kind[Kind::Owner as usize] > frames / 8, "{by_kind:?}");
    assert!(
        s.unsigned > 0 && s.bad_signature > 0 && s.replayed > 0 && s.setups_refused > 0,
        "{s:?}"
    );
    std::println!("signing fuzz: {frames} frames, {delivered} delivered {by_kind:?}, signing {s:?}");
}

/// A signing sink whose owner keeps settings (a RAM stand-in store).
struct KeptSink {
    signed: SignedSink,
    store: fc_storage::Store<fc_storage::RamFlash<4096>>,
}

impl MavSink for KeptSink {
    type Error = Infallible;
    fn send(&mut self, to: Peer, msg: &MavMessage) -> Result<(), Infallible> {
        self.signed.send(to, msg)
    }
    fn signing(&mut self) -> Option<&mut crate::signing::Signing> {
        Some(&mut self.signed.signing)
    }
    fn storage(&mut self) -> Option<&mut dyn fc_storage::Persist> {
        Some(&mut self.store)
    }
}

#[test]
fn parameters_and_the_signing_key_are_stored_and_boot_again() {
    use fc_storage::{Persist, RamFlash, Store};
    let (store, _) = Store::open(RamFlash::blank(), 0..4096).unwrap();
    let mut sink = KeptSink {
        signed: SignedSink::default(),
        store,
    };
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let gain = params::index_of(b"PD_ROLL_P").unwrap();
    let want = (PARAMS[gain].get)(&Settings::os4()) * 1.5;
    v.handle(&param_set("PD_ROLL_P", want), &mut sink, &Still, 0).unwrap();
    // Refused: not stored.
    v.handle(&param_set("CTL_ID", 99.0), &mut sink, &Still, 0).unwrap();
    // An automatic mode's setting, in the one table: stored under the key
    // it had when the modes' settings were a table of their own after the
    // loop's 52 (so a store written then still boots).
    let nav = params::index_of(b"MIS_TAKEOFF_ALT").unwrap();
    assert_eq!(nav, 52);
    let nav_value = NavSettings::default().takeoff_alt_m * 0.5;
    v.handle(&param_set("MIS_TAKEOFF_ALT", nav_value), &mut sink, &Still, 0)
        .unwrap();
    let setup = MavMessage::SETUP_SIGNING(SETUP_SIGNING_DATA {
        target_system: 1,
        target_component: 1,
        secret_key: [7; 32],
        initial_timestamp: 5_000,
    });
    v.handle(&setup, &mut sink, &Still, 0).unwrap();
    assert!(sink.signed.signing.is_on());
    let texts = sink.signed.sent.texts();
    assert!(!texts.iter().any(|t| t.contains("not stored")), "{texts:?}");
    let st = &mut sink.store;
    assert_eq!(st.param(gain as u16), Ok(Some(want)));
    let ctl = params::index_of(b"CTL_ID").unwrap() as u16;
    assert_eq!(Persist::param(st, ctl), Ok(None));
    assert_eq!(st.param(nav as u16), Ok(Some(nav_value)));
    assert_eq!(st.signing(), Ok(Some(([7; 32], 5_000))));
    // Power off and on: the bytes are all that is left.
    let bytes = *sink.store.into_flash().bytes();
    let (mut st, boot) = Store::open(RamFlash::<4096>::holding(&bytes), 0..4096).unwrap();
    assert_eq!(boot, fc_storage::Boot::Found);
    let loaded = fc_loop::params::load(Settings::os4(), |i| st.param(i)).unwrap();
    assert_eq!((loaded.taken, loaded.refused.0), (2, 0));
    let mut v = MavVehicle::new(loaded.settings, 1).unwrap();
    assert_eq!(v.nav_settings().takeoff_alt_m, nav_value);
    let mut sent = Sent::default();
    v.handle(
        &MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: 1,
        }),
        &mut sent,
        &Still,
        0,
    )
    .unwrap();
    let values = sent.pick(|m| match m {
        MavMessage::PARAM_VALUE(p) => Some((usize::from(p.param_index), p.param_value)),
        _ => None,
    });
    assert!(
        values.contains(&(gain, want)) && values.contains(&(nav, nav_value)),
        "{values:?}"
    );
}

/// `firmware-mavlink` steps a `HIL_SENSOR` in three halves on the split
/// vehicle (its estimator's task, its controller's, the step's end) and
/// hands every other message to the link's task: through alignment, a
/// re-designing parameter write, arming (which designs) and a take-off,
/// every message the halves send is the one [`MavVehicle::handle`] sends,
/// in the same order, and the motors run.
#[test]
fn the_images_halves_send_what_one_call_sends() {
    let mut whole = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut parts = MavVehicle::new(Settings::os4(), 1).unwrap();
    let (mut a, mut b) = (Sent::default(), Sent::default());
    let mut script: Vec<MavMessage> = (0..2_000).flat_map(|k| at_rest(k * 1000)).collect();
    let w_pos = PARAMS[param_index_of(b"LQR_W_POS").unwrap()].get;
    script.extend([
        param_set("LQR_W_POS", 1.1 * w_pos(whole.settings())),
        set_mode(FlightMode::Hold),
        command(1.0, 0.0),
        command_of(MavCmd::MAV_CMD_NAV_TAKEOFF, [f32::NAN; 7]),
    ]);
    script.extend((2_000..3_000).flat_map(|k| at_rest(k * 1000)));
    for m in &script {
        whole.handle(m, &mut a, &Still, 0).unwrap();
        let (shared, ctrl) = parts.split();
        match m {
            MavMessage::HIL_SENSOR(s) => {
                if let Some(step) = shared.sensor_begin(s, &Still, 0) {
                    let flown = fly_sensor_step(&mut Exclusive(&mut *shared), ctrl, &step, &Still);
                    shared.sensor_end(&step, flown, &Still, &mut b).unwrap();
                }
            }
            m => shared.handle(ctrl, m, &mut b, &Still, 0).unwrap(),
        }
    }
    assert_eq!(a.count("HIL_ACTUATOR_CONTROLS"), 3_000);
    assert_eq!(a.0, b.0);
    assert!(
        parts.armed() && parts.motors().iter().all(|&m| m > 0.1),
        "{:?}",
        parts.motors()
    );
    assert_eq!(parts.mode(), FlightMode::Takeoff);
}

/// The commander runs before the estimator and the controller, as in
/// every protocol's step (commander → estimator → controller): in a
/// take-off, each step's controller flies the route's set-point at its own
/// sample's time, the one the vehicle holds after the step, not the step
/// before's (a 1 ms lag at 1 kHz).
#[test]
fn a_take_off_flies_each_samples_own_setpoint() {
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut sent = Sent::default();
    for m in (0..2_000).flat_map(|k| at_rest(k * 1000)) {
        v.handle(&m, &mut sent, &Still, 0).unwrap();
    }
    for m in [
        set_mode(FlightMode::Hold),
        command(1.0, 0.0),
        command_of(MavCmd::MAV_CMD_NAV_TAKEOFF, [f32::NAN; 7]),
    ] {
        v.handle(&m, &mut sent, &Still, 0).unwrap();
    }
    assert_eq!(v.mode(), FlightMode::Takeoff);
    let (shared, ctrl) = v.split();
    let mut heights = Vec::new();
    for m in (2_000..2_500).flat_map(|k| at_rest(k * 1000)) {
        let MavMessage::HIL_SENSOR(s) = &m else {
            shared.handle(ctrl, &m, &mut sent, &Still, 0).unwrap();
            continue;
        };
        let Some(step) = shared.sensor_begin(s, &Still, 0) else {
            continue;
        };
        let job = step.job.and_then(|j| j.control);
        let flown = fly_sensor_step(&mut Exclusive(&mut *shared), ctrl, &step, &Still);
        shared.sensor_end(&step, flown, &Still, &mut sent).unwrap();
        if let Some(job) = job {
            assert_eq!(job.sp.pos_ned_m, shared.lp.setpoint().pos_ned_m, "at {} µs", step.t_us);
            heights.push(job.sp.pos_ned_m[2]);
        }
    }
    // The route climbs: every flown set-point is a new one.
    assert!(heights.len() > 100, "{}", heights.len());
    assert!(heights.windows(2).all(|w| w[1] < w[0]), "{heights:?}");
}

/// HIL samples of a vehicle rolled to `roll_rad` about body x, turning at
/// `p_radps` and otherwise at rest: the accelerometer reads gravity in the
/// rolled frame, f = (0, −g sin φ, −g cos φ) (body FRD).
fn rolled(t_us: u64, roll_rad: f32, p_radps: f32) -> [MavMessage; 2] {
    let [state, MavMessage::HIL_SENSOR(mut s)] = at_rest(t_us) else {
        unreachable!()
    };
    s.xgyro = p_radps;
    s.yacc = -9.81 * roll_rad.sin();
    s.zacc = -9.81 * roll_rad.cos();
    [state, MavMessage::HIL_SENSOR(s)]
}

/// The supervisor's tumble check, as PX4's failure detector with its
/// defaults: armed on the ground, a vehicle that rolls over (5 rad/s to
/// 86°, as with a motor wired in the wrong place) is disarmed within the
/// roll, told as PX4 tells it (`STATUSTEXT` EMERGENCY); one that rolls to
/// 45° and back flies on.
#[test]
fn a_vehicle_that_flips_as_it_lifts_off_is_locked_down() {
    for (to_rad, locked) in [(1.5f32, true), (0.785, false)] {
        let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
        let mut out = Sent::default();
        let mut t = rest(&mut v, &mut out, 1_000_000, 2000);
        v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
        assert!(v.armed());
        let mut out = Sent::default();
        // Over and back at 5 rad/s, then at rest.
        let n = (to_rad / 5.0 * 1000.0) as u64;
        let mut disarmed_at = None;
        for k in 0..2 * n {
            let (roll, p) = if k < n {
                (5.0 * k as f32 * 1e-3, 5.0)
            } else {
                (to_rad - 5.0 * (k - n) as f32 * 1e-3, -5.0)
            };
            for m in rolled(t, roll, p) {
                v.handle(&m, &mut out, &Still, 0).unwrap();
            }
            if !v.armed() && disarmed_at.is_none() {
                disarmed_at = Some(roll);
            }
            t += 1000;
        }
        rest(&mut v, &mut out, t, 500);
        let said = out.texts();
        if locked {
            // Past 60°, before the top of the roll.
            let at = disarmed_at.expect("disarmed");
            assert!((1.047..1.2).contains(&at), "disarmed at {at} rad");
            assert_eq!(said, ["critical failure: tilt beyond 60°, lockdown"]);
            let severities: Vec<_> = out
                .0
                .iter()
                .filter_map(|(_, m)| match m {
                    MavMessage::STATUSTEXT(t) => Some(t.severity),
                    _ => None,
                })
                .collect();
            assert_eq!(severities, [MavSeverity::MAV_SEVERITY_EMERGENCY]);
            assert!(v.motors().iter().all(|&m| m == 0.0), "{:?}", v.motors());
        } else {
            assert!(v.armed() && said.is_empty(), "{said:?}");
        }
    }
}

/// A trajectory a host hands the vehicle (`sil-host px4-hil --trajectory`)
/// flies in Offboard from its pieces, against the polynomial's own values
/// and derivatives: north = 1 + t², heading 0.2 rad over 1 s, started 0.1 s
/// after it is handed over, relative to the hold it starts from. Refused
/// disarmed, outside Offboard and when undefined, and then nothing changes;
/// while it flies the missing stream is no loss of Offboard; a streamed
/// set-point takes over.
#[cfg(feature = "handover")]
#[test]
fn a_trajectory_handed_over_flies_in_offboard_from_its_pieces() {
    use fc_loop::modes::ModeRefusal;
    use fc_loop::trajectory::{Definition, Piece, StartOptions, TrajectoryError, TrajectoryMemory};
    let mut poly = [[0.0f32; 8]; 4];
    poly[0][0] = 1.0;
    poly[0][2] = 1.0;
    poly[3][0] = 0.2;
    let memory: &'static mut TrajectoryMemory = Box::leak(Box::new(TrajectoryMemory::new()));
    memory.write(0, &Piece { poly, duration_s: 1.0 }.to_bytes()).unwrap();
    memory.define(1, Definition::new(0, 1).unwrap()).unwrap();
    let memory: &'static TrajectoryMemory = memory;
    let options = StartOptions {
        time_scale: 1.0,
        reversed: false,
        relative_position: true,
        relative_yaw: false,
    };
    let mut v = MavVehicle::new(Settings::os4(), 1).unwrap();
    let mut out = Sent::default();
    let mut t = rest(&mut v, &mut out, 0, 2_000);
    assert_eq!(v.fly_trajectory(memory, 1, options, t), Err(ModeRefusal::Disarmed));
    v.handle(&set_mode(FlightMode::Hold), &mut out, &Still, 0).unwrap();
    v.handle(&command(1.0, 0.0), &mut out, &Still, 0).unwrap();
    assert!(v.armed());
    assert_eq!(
        v.fly_trajectory(memory, 1, options, t),
        Err(ModeRefusal::Trajectory(None))
    );
    let hold = SET_POSITION_TARGET_LOCAL_NED_DATA {
        x: 0.5,
        y: 2.0,
        z: -1.0,
        target_system: 1,
        type_mask: PositionTargetTypemask::empty(),
        coordinate_frame: MavFrame::MAV_FRAME_LOCAL_NED,
        ..Default::default()
    };
    let stream = MavMessage::SET_POSITION_TARGET_LOCAL_NED(hold);
    v.handle(&stream, &mut out, &Still, 0).unwrap();
    v.handle(&set_mode(FlightMode::Offboard), &mut out, &Still, 0).unwrap();
    assert_eq!(v.mode(), FlightMode::Offboard);
    assert_eq!(
        v.fly_trajectory(memory, 2, options, t),
        Err(ModeRefusal::Trajectory(Some(TrajectoryError::Undefined)))
    );
    assert_eq!(v.setpoint().pos_ned_m, Vector3::new(0.5, 2.0, -1.0), "nothing changed");
    let start_us = t + 100_000;
    v.handle(&stream, &mut out, &Still, 0).unwrap();
    v.fly_trajectory(memory, 1, options, start_us).unwrap();
    // 1.6 s without a streamed set-point (Offboard's loss is 1 s): the
    // pieces fly, then rest at their end.
    for _ in 0..1_600 {
        t = rest(&mut v, &mut out, t, 1);
        let tau = (t - 1000).saturating_sub(start_us) as f32 * 1e-6;
        let s = tau.min(1.0);
        let sp = v.setpoint();
        let want_n = 0.5 + s * s;
        let want_v = if tau <= 1.0 { 2.0 * s } else { 0.0 };
        assert!(
            (sp.pos_ned_m - Vector3::new(want_n, 2.0, -1.0)).amax() < 1e-5,
            "{tau} s: {sp:?}"
        );
        assert!((sp.vel_ned_mps[0] - want_v).abs() < 1e-4, "{tau} s: {sp:?}");
        if tau < 1.0 {
            assert!((sp.acc_ned_mps2[0] - 2.0).abs() < 1e-3, "{tau} s: {sp:?}");
        }
        // Relative position only: the heading is the trajectory's.
        assert!((sp.yaw_rad - 0.2).abs() < 1e-6, "{tau} s: {sp:?}");
        assert_eq!(v.mode(), FlightMode::Offboard, "{tau} s");
    }
    assert_eq!(*v.flight_loop().setpoint(), v.setpoint());
    v.handle(&stream, &mut out, &Still, 0).unwrap();
    assert_eq!(
        v.setpoint().pos_ned_m,
        Vector3::new(0.5, 2.0, -1.0),
        "the stream took over"
    );
}
