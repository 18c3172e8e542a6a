//! FlightLoop: handshake, lockstep, every failure class of the issue, the
//! failsafe and its recovery, and a fuzzer over raw bytes.

use super::*;
use fc_proto::{encode, FrameDecoder, FromFc, ToFc, MAX_FRAME};
use hal_shim::host::LoopbackLink;
use proptest::prelude::*;

struct FakeClock(core::cell::Cell<u32>);
impl CycleClock for FakeClock {
    fn now(&self) -> u32 {
        let v = self.0.get();
        self.0.set(v.wrapping_add(1000));
        v
    }
    fn hz(&self) -> u32 {
        168_000_000
    }
}

fn frame(m: &ToFc) -> Vec<u8> {
    let mut b = [0u8; MAX_FRAME];
    let n = encode(m, &mut b).unwrap();
    b[..n].to_vec()
}

fn hover_state() -> [f32; 13] {
    let mut s = [0.0f32; 13];
    s[2] = -1.0;
    s[6] = 1.0;
    s
}

struct Rig {
    fc: FlightLoop,
    link: LoopbackLink,
    clock: FakeClock,
}

impl Rig {
    fn new() -> Self {
        Self::with(FcConfig::default())
    }
    fn with(cfg: FcConfig) -> Self {
        Self {
            fc: FlightLoop::new(cfg).unwrap(),
            link: LoopbackLink::default(),
            clock: FakeClock(0.into()),
        }
    }
    fn send_bytes(&mut self, bytes: &[u8], now_us: u64) -> Vec<FromFc> {
        self.link.rx.extend(bytes.iter().copied());
        // Drain everything (service reads a bounded amount per call).
        for _ in 0..1000 {
            self.fc.service(&mut self.link, &self.clock, now_us).unwrap();
            if self.link.rx.is_empty() {
                break;
            }
        }
        let mut d = FrameDecoder::<MAX_FRAME>::new();
        let out: Vec<FromFc> = self
            .link
            .tx
            .iter()
            .filter_map(|b| d.push::<FromFc>(*b))
            .map(|r| r.unwrap())
            .collect();
        self.link.tx.clear();
        out
    }
    fn send(&mut self, m: &ToFc, now_us: u64) -> Vec<FromFc> {
        self.send_bytes(&frame(m), now_us)
    }
    fn open(&mut self) {
        let r = self.send(
            &ToFc::Hello {
                version: PROTOCOL_VERSION,
            },
            0,
        );
        assert_eq!(
            r,
            vec![FromFc::HelloAck {
                version: PROTOCOL_VERSION,
                accepted: true
            }]
        );
    }
}

#[test]
fn handshake_gates_the_session() {
    let mut rig = Rig::new();
    // Before the handshake, sensor frames are not answered.
    assert!(rig
        .send(
            &ToFc::Sensor {
                seq: 1,
                t_us: 0,
                state: hover_state()
            },
            0
        )
        .is_empty());
    assert_eq!(rig.fc.counters().unexpected, 1);
    let r = rig.send(
        &ToFc::Hello {
            version: PROTOCOL_VERSION + 1,
        },
        0,
    );
    assert_eq!(
        r,
        vec![FromFc::HelloAck {
            version: PROTOCOL_VERSION,
            accepted: false
        }]
    );
    assert!(!rig.fc.session_open());
    rig.open();
    assert!(rig.fc.session_open());
}

#[test]
fn lockstep_answers_each_step_with_its_sequence_number() {
    let mut rig = Rig::new();
    rig.open();
    for seq in 1..=5u32 {
        let r = rig.send(
            &ToFc::Sensor {
                seq,
                t_us: seq as u64 * 2000,
                state: hover_state(),
            },
            seq as u64 * 2000,
        );
        match r.as_slice() {
            [FromFc::Actuator {
                seq: s,
                u,
                failsafe: false,
            }, FromFc::Telemetry { seq: s2, cycles, .. }] => {
                assert_eq!((*s, *s2), (seq, seq));
                // Hovering at the setpoint: hover thrust, no torques.
                assert!((u[0] - 6.3765).abs() < 1e-3 && u[1].abs() < 1e-4, "{u:?}");
                assert_eq!(*cycles, 1000);
            }
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(rig.fc.counters().ok, 6);
}

#[test]
fn bad_frames_are_dropped_and_counted_then_flight_continues() {
    let mut rig = Rig::new();
    rig.open();
    let good = frame(&ToFc::Sensor {
        seq: 1,
        t_us: 0,
        state: hover_state(),
    });
    // Corrupt CRC.
    let mut bad = good.clone();
    bad[3] ^= 0x80; // never creates a 0x00 delimiter (that would split the frame in two)
    assert_ne!(bad[3], 0);
    assert!(rig.send_bytes(&bad, 0).is_empty());
    // Truncated.
    let mut trunc = good[..good.len() / 2].to_vec();
    trunc.push(0);
    assert!(rig.send_bytes(&trunc, 0).is_empty());
    // Oversized.
    let mut big = vec![7u8; 500];
    big.push(0);
    assert!(rig.send_bytes(&big, 0).is_empty());
    // Well-framed nonsense (valid CRC, not a message).
    let mut raw = [0u8; 16];
    raw[..4].copy_from_slice(&[0xff, 0xee, 0xdd, 0xcc]);
    let crc = crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(&raw[..4]);
    raw[4..8].copy_from_slice(&crc.to_le_bytes());
    let mut enc = [0u8; 32];
    let n = cobs::try_encode(&raw[..8], &mut enc).unwrap();
    let mut nonsense = enc[..n].to_vec();
    nonsense.push(0);
    assert!(rig.send_bytes(&nonsense, 0).is_empty());
    let c = rig.fc.counters();
    assert_eq!((c.bad_crc + c.bad_cobs, c.oversized, c.bad_message), (2, 1, 1), "{c:?}");
    // The next good frame is answered.
    assert_eq!(rig.send_bytes(&good, 0).len(), 2);
}

#[test]
fn out_of_order_and_invalid_values_are_rejected() {
    let mut rig = Rig::new();
    rig.open();
    assert_eq!(
        rig.send(
            &ToFc::Sensor {
                seq: 10,
                t_us: 20_000,
                state: hover_state()
            },
            0
        )
        .len(),
        2
    );
    let held = rig.fc.output();
    let r = rig.send(
        &ToFc::Sensor {
            seq: 10,
            t_us: 20_000,
            state: hover_state(),
        },
        0,
    );
    assert_not_flown(&r, 10, held, 1);
    let r = rig.send(
        &ToFc::Sensor {
            seq: 9,
            t_us: 18_000,
            state: hover_state(),
        },
        0,
    );
    assert_not_flown(&r, 9, held, 2);
    assert_eq!(rig.fc.counters().out_of_order, 2);
    let before = rig.fc.output();
    let mut nan = hover_state();
    nan[4] = f32::NAN;
    let r = rig.send(
        &ToFc::Sensor {
            seq: 11,
            t_us: 22_000,
            state: nan,
        },
        1000,
    );
    // Answered (lockstep continues) with the unchanged output; counted.
    assert!(matches!(r[0], FromFc::Actuator { seq: 11, .. }));
    assert_eq!(rig.fc.output(), before);
    let mut bad_q = hover_state();
    bad_q[6] = 2.0;
    rig.send(
        &ToFc::Sensor {
            seq: 12,
            t_us: 24_000,
            state: bad_q,
        },
        2000,
    );
    let mut bad_sp = WireSetpoint {
        pos: [0.0, 0.0, -1.0],
        vel: [0.0; 3],
        acc: [0.0; 3],
        jerk: [0.0; 3],
        yaw: 0.0,
        yaw_rate: 0.0,
    };
    bad_sp.pos[0] = f32::INFINITY;
    rig.send(&ToFc::Setpoint(bad_sp), 2000);
    assert_eq!(rig.fc.counters().invalid_values, 3);
}

#[test]
fn free_running_failsafe_after_50_ms_without_valid_sensor_and_recovery() {
    // The real-time watchdog of a vehicle: `now_us` is the clock, the
    // frames' time is not used (all 0 here).
    let mut rig = Rig::with(FcConfig {
        time_base: TimeBase::FreeRunning,
        ..FcConfig::default()
    });
    rig.open();
    rig.send(
        &ToFc::Sensor {
            seq: 1,
            t_us: 0,
            state: hover_state(),
        },
        1_000,
    );
    rig.fc.check_timeout(40_000);
    assert!(!rig.fc.failsafe());
    // NaN frames do not refresh the timer.
    let mut nan = hover_state();
    nan[0] = f32::NAN;
    rig.send(
        &ToFc::Sensor {
            seq: 2,
            t_us: 0,
            state: nan,
        },
        45_000,
    );
    rig.fc.check_timeout(51_500);
    assert!(rig.fc.failsafe());
    rig.fc.check_timeout(52_000);
    assert_eq!(rig.fc.counters().failsafe_entries, 1, "one entry, counted once");
    let u = rig.fc.output();
    assert!(
        (u[0] - 0.85 * 6.3765).abs() < 1e-3 && u[1] == 0.0 && u[2] == 0.0 && u[3] == 0.0,
        "{u}"
    );
    // Valid data again: control resumes.
    let r = rig.send(
        &ToFc::Sensor {
            seq: 3,
            t_us: 0,
            state: hover_state(),
        },
        60_000,
    );
    assert!(matches!(r[0], FromFc::Actuator { failsafe: false, .. }));
    assert!(!rig.fc.failsafe());
    // The episode stays visible in the telemetry after recovery.
    assert!(r
        .iter()
        .any(|m| matches!(m, FromFc::Telemetry { counters, .. } if counters.failsafe_entries == 1)));
}

/// The answer to a sensor frame that was not flown: the held output `u`
/// for its `seq`, and telemetry with no controller time and the
/// out-of-order count `n` (so a lockstep client never waits in vain).
fn assert_not_flown(r: &[FromFc], seq: u32, u: Input<f32>, n: u32) {
    let held = [u[0], u[1], u[2], u[3]];
    match r {
        [FromFc::Actuator { seq: s, u, .. }, FromFc::Telemetry {
            seq: s2,
            cycles: 0,
            counters,
            ..
        }] => {
            assert_eq!((*s, *s2, *u), (seq, seq, held));
            assert_eq!(counters.out_of_order, n);
        }
        other => panic!("{other:?}"),
    }
}

/// The answer to sensor frame `seq` came from the controller (not the failsafe).
fn assert_flown(r: &[FromFc], seq: u32) {
    assert!(
        matches!(r.first(), Some(FromFc::Actuator { seq: s, failsafe: false, .. }) if *s == seq),
        "{r:?}"
    );
}

/// A lockstep sensor frame at simulated time `t_us`.
fn sensor_at(seq: u32, t_us: u64, state: [f32; 13]) -> ToFc {
    ToFc::Sensor { seq, t_us, state }
}

#[test]
fn lockstep_wall_time_is_not_a_timeout() {
    // A host that takes 10 s of wall time between two frames 2 ms apart in
    // simulated time: no failsafe, whatever the real clock says.
    let mut rig = Rig::new();
    rig.open();
    rig.send(&sensor_at(1, 2_000, hover_state()), 0);
    rig.fc.check_timeout(10_000_000);
    let r = rig.send(&sensor_at(2, 4_000, hover_state()), 10_000_000);
    assert_flown(&r, 2);
    assert_eq!((rig.fc.failsafe(), rig.fc.counters().failsafe_entries), (false, 0));
}

#[test]
fn lockstep_simulated_gap_past_the_timeout_is_a_failsafe_episode() {
    // Simulated time jumps 200 ms between two frames: the vehicle flew that
    // long without the loop. Counted as one episode; the valid frame that
    // ends it is flown by the controller, not the failsafe.
    let mut rig = Rig::new();
    rig.open();
    rig.send(&sensor_at(1, 2_000, hover_state()), 0);
    let r = rig.send(&sensor_at(2, 202_000, hover_state()), 0);
    assert_flown(&r, 2);
    assert!(r
        .iter()
        .any(|m| matches!(m, FromFc::Telemetry { counters, .. } if counters.failsafe_entries == 1)));
    // A gap up to the timeout is not one.
    rig.send(&sensor_at(3, 252_000, hover_state()), 0);
    assert_eq!(rig.fc.counters().failsafe_entries, 1);
}

#[test]
fn lockstep_invalid_frames_past_the_timeout_enter_the_failsafe_and_valid_ones_end_it() {
    let mut rig = Rig::new();
    rig.open();
    rig.send(&sensor_at(1, 2_000, hover_state()), 0);
    let mut nan = hover_state();
    nan[0] = f32::NAN;
    // 2 ms frames, all NaN: the failsafe takes over once 50 ms of simulated time have passed.
    let mut entered_at = None;
    for k in 2..40u32 {
        let r = rig.send(&sensor_at(k, u64::from(k) * 2_000, nan), 0);
        if let FromFc::Actuator { failsafe: true, u, .. } = r[0] {
            entered_at.get_or_insert((k, u));
        }
    }
    let (k, u) = entered_at.expect("failsafe entered");
    assert_eq!(k, 27, "first frame more than 50 ms after the last valid one (t = 2 ms)");
    assert!(
        (u[0] - 0.85 * 6.3765).abs() < 1e-3 && u[1..].iter().all(|v| *v == 0.0),
        "{u:?}"
    );
    let r = rig.send(&sensor_at(40, 80_000, hover_state()), 0);
    assert_flown(&r, 40);
    assert_eq!(rig.fc.counters().failsafe_entries, 1);
}

#[test]
fn lockstep_time_that_does_not_increase_is_out_of_order() {
    let mut rig = Rig::new();
    rig.open();
    rig.send(&sensor_at(1, 4_000, hover_state()), 0);
    let held = rig.fc.output();
    // A newer sequence number with an older or equal time: not flown, counted, answered.
    assert_not_flown(&rig.send(&sensor_at(2, 4_000, hover_state()), 0), 2, held, 1);
    assert_not_flown(&rig.send(&sensor_at(3, 2_000, hover_state()), 0), 3, held, 2);
    assert_eq!(rig.send(&sensor_at(4, 6_000, hover_state()), 0).len(), 2);
    // An absurd jump (here 2⁶⁰ µs) does not become the clock: dropped and
    // counted, and the flight goes on from where it was.
    assert_not_flown(&rig.send(&sensor_at(5, 1 << 60, hover_state()), 0), 5, held, 3);
    assert_eq!(rig.send(&sensor_at(6, 8_000, hover_state()), 0).len(), 2);
    assert_eq!(rig.fc.counters().failsafe_entries, 0);
}

#[test]
fn every_controller_can_be_selected_over_the_link() {
    let mut rig = Rig::new();
    rig.open();
    let ids: Vec<u8> = fc_core::control::SPECS.iter().filter_map(|r| r.wire_id).collect();
    assert_eq!(ids, (0..8).collect::<Vec<u8>>(), "protocol v2's ids");
    for (i, id) in ids.iter().enumerate() {
        rig.send(
            &ToFc::Select {
                controller: *id,
                feedforward: true,
            },
            0,
        );
        let r = rig.send(
            &ToFc::Sensor {
                seq: 100 + i as u32,
                t_us: (i as u64 + 1) * 5_000,
                state: hover_state(),
            },
            0,
        );
        match r[0] {
            FromFc::Actuator { u, .. } => assert!((u[0] - 6.3765).abs() < 1e-2, "{id:?}: {u:?}"),
            ref other => panic!("{other:?}"),
        }
    }
    assert_eq!(rig.fc.counters().invalid_values, 0);
    assert_eq!(rig.fc.selections(), 8);
    // An id no controller has is dropped and counted; the controller stays.
    rig.send(
        &ToFc::Select {
            controller: 8,
            feedforward: true,
        },
        0,
    );
    assert_eq!((rig.fc.counters().bad_message, rig.fc.selections()), (1, 8));
}

proptest! {
    // 2 000 cases per test run; `FUZZ_CASES=N` for a long run.
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(2000)
    ))]

    /// Random bytes, random cuts of valid frames, random bit flips: the
    /// decoder and the core never panic, and a valid frame after any of it
    /// is still answered.
    #[test]
    fn fuzz_the_link(noise in proptest::collection::vec(any::<u8>(), 0..600), flips in proptest::collection::vec((0usize..80, any::<u8>()), 0..8)) {
        let mut rig = Rig::new();
        rig.open();
        let mut bytes = noise;
        let mut f = frame(&ToFc::Sensor { seq: 5, t_us: 0, state: hover_state() });
        for (i, x) in flips {
            let k = i % f.len();
            f[k] ^= x;
        }
        bytes.extend_from_slice(&f);
        let _ = rig.send_bytes(&bytes, 0);
        // Resync and a fresh valid step.
        let mut tail = vec![0u8];
        tail.extend(frame(&ToFc::Sensor { seq: 1_000_000, t_us: 1_000_000, state: hover_state() }));
        let r = rig.send_bytes(&tail, 0);
        let answered = matches!(r.first(), Some(FromFc::Actuator { seq: 1_000_000, .. }));
        prop_assert!(answered, "no answer after noise: {:?}", r);
    }
}

#[test]
fn a_slow_controllers_own_period_is_not_a_timeout() {
    // The thesis MPC steps at 4 Hz: frames 250 ms apart are on time (the
    // timeout is at least two of its periods), 600 ms is a gap.
    let mut rig = Rig::new();
    rig.open();
    let id = fc_core::control::ControllerSpec::new(fc_core::control::Family::Mpc, AttitudeForm::Euler)
        .with_preset(fc_core::control::Preset::Thesis)
        .to_wire()
        .unwrap()
        .0;
    rig.send(
        &ToFc::Select {
            controller: id,
            feedforward: true,
        },
        0,
    );
    for k in 1..=4u32 {
        rig.send(&sensor_at(k, u64::from(k) * 250_000, hover_state()), 0);
    }
    assert_eq!(rig.fc.counters().failsafe_entries, 0);
    rig.send(&sensor_at(5, 1_600_000, hover_state()), 0);
    assert_eq!(rig.fc.counters().failsafe_entries, 1);
}

#[test]
fn finite_but_absurd_sensor_frames_are_refused_not_flown() {
    let mut rig = Rig::new();
    rig.open();
    rig.send(&sensor_at(1, 2_000, hover_state()), 0);
    let held = rig.fc.output();
    // A 100 m jump 2 ms after the last frame (the vehicle's top speed would
    // allow 0.2 m + 1 m), and body rates of 1e30 rad/s: counted as invalid,
    // answered with the held output.
    let mut jump = hover_state();
    jump[0] = 100.0;
    let mut spin = hover_state();
    spin[10] = 1e30;
    for (k, s) in [(2u32, jump), (3, spin)] {
        let r = rig.send(&sensor_at(k, u64::from(k) * 2_000, s), 0);
        assert!(
            matches!(r[0], FromFc::Actuator { seq, u, .. } if seq == k && u == [held[0], held[1], held[2], held[3]]),
            "{r:?}"
        );
    }
    assert_eq!(rig.fc.counters().invalid_values, 2);
    // A 0.5 m correction (a position fix) is plausible and flown.
    let mut fix = hover_state();
    fix[0] = 0.5;
    rig.send(&sensor_at(4, 8_000, fix), 0);
    assert_eq!(rig.fc.counters().invalid_values, 2);
    assert_ne!(
        rig.fc.output(),
        held,
        "flown: the controller reacts to the 0.5 m offset"
    );
}

/// Sensor flights: every `Imu` frame (1 kHz) steps the estimator and is
/// answered with its `Nav`; the fast MPC (1 ms) runs at every sample once
/// the estimator is aligned. (Slower controllers run on their grid and the
/// answers repeat the last output between runs: `schedule`'s tests.)
#[test]
fn imu_steps_run_the_estimator_and_the_fast_mpc_every_millisecond() {
    let mut rig = Rig::new();
    rig.open();
    let spec = ControllerSpec::new(Family::Mpc, AttitudeForm::Quaternion);
    let (controller, feedforward) = spec.to_wire().unwrap();
    rig.send(
        &ToFc::Select {
            controller,
            feedforward,
        },
        0,
    );
    assert_eq!(rig.fc.period_us(), 1_000);
    let mut sp = Setpoint::hold(Vector3::new(1.0, 0.0, -1.0), 0.0);
    sp.vel_ned_mps = Vector3::zeros();
    rig.send(&ToFc::Setpoint(setpoint_to_wire(&sp)), 0);
    let fix = fc_proto::WireFix {
        age_us: 0,
        pos: Some([0.0, 0.0, -1.0]),
        pos_sigma: [0.002; 3],
        vel: None,
        vel_sigma: 0.0,
        yaw: Some(0.0),
        yaw_sigma: 0.01,
        alt: None,
        alt_sigma: 0.0,
    };
    let (mut ran, mut last_u) = (Vec::new(), None);
    for k in 1..=60u32 {
        if k % 10 == 1 {
            rig.send(&ToFc::Fix(fix), 0);
        }
        let t_us = u64::from(k) * 1_000;
        let r = rig.send(
            &ToFc::Imu {
                seq: k,
                t_us,
                gyro: [0.0; 3],
                accel: [0.0, 0.0, -9.81],
            },
            0,
        );
        let [FromFc::Actuator { u, .. }, FromFc::Telemetry { qp_iterations, .. }, FromFc::Nav { mode, .. }, FromFc::NavBias { seq, sigma, .. }] =
            r[..]
        else {
            panic!("step {k}: {r:?}")
        };
        // The biases' σ complete the covariance diagonal on the wire.
        assert_eq!(seq, k);
        let diag = rig.fc.navigator().estimator().sigmas();
        assert_eq!(sigma.as_slice(), &diag.as_slice()[9..], "step {k}");
        if mode == 1 {
            if qp_iterations > 0 {
                ran.push(t_us);
            } else {
                assert_eq!(Some(u), last_u, "step {k}: the output is held between runs");
            }
        }
        last_u = Some(u);
    }
    // Aligned after 25 samples; then the MPC at every sample.
    assert!(ran.len() >= 30, "{ran:?}");
    assert_eq!(ran.windows(2).filter(|w| w[1] - w[0] != 1_000).count(), 0, "{ran:?}");
    assert_eq!(rig.fc.counters().invalid_values, 0);
}

#[test]
fn parameters_over_the_wire_are_checked_echoed_and_redesign_only_before_the_first_step() {
    let mut rig = Rig::new();
    rig.open();
    let mass = params::index_of(b"VEH_MASS").unwrap() as u16;
    let param = |r: &[FromFc]| match r {
        [FromFc::Param {
            index,
            count,
            id,
            value,
            refusal,
        }] => (*index, *count, *id, *value, *refusal),
        other => panic!("{other:?}"),
    };
    // Read: the OS4's mass, named as MAVLink names it.
    let (i, count, id, value, refusal) = param(&rig.send(&ToFc::ParamRead { index: mass }, 0));
    assert_eq!(
        (i, count as usize, value, refusal),
        (mass, params::PARAMS.len(), 0.65, 0)
    );
    assert_eq!(&id[..9], b"VEH_MASS\0");
    // Non-physical: refused (code 2, out of range), the old value in force.
    let (_, _, _, value, refusal) = param(&rig.send(
        &ToFc::ParamSet {
            index: mass,
            value: -1.0,
        },
        0,
    ));
    assert_eq!((value, refusal), (0.65, 2));
    // Accepted before the first step: the controller is designed for it.
    let (_, _, _, value, refusal) = param(&rig.send(
        &ToFc::ParamSet {
            index: mass,
            value: 0.8,
        },
        0,
    ));
    assert_eq!((value, refusal), (0.8, 0));
    assert_eq!(rig.fc.vehicle().mass_kg, 0.8);
    // Hover now needs 0.8 g of thrust: the first step's output says so.
    let r = rig.send(
        &ToFc::Sensor {
            seq: 1,
            t_us: 2_000,
            state: hover_state(),
        },
        2_000,
    );
    let FromFc::Actuator { u, .. } = r[0] else {
        panic!("{r:?}")
    };
    assert!((u[0] - 0.8 * 9.81).abs() < 1e-3, "{u:?}");
    // In flight: a re-design is refused (code 7); a failsafe setting is not.
    let (_, _, _, value, refusal) = param(&rig.send(
        &ToFc::ParamSet {
            index: mass,
            value: 0.9,
        },
        2_000,
    ));
    assert_eq!((value, refusal), (0.8, 7));
    let fs = params::index_of(b"FS_TIMEOUT_MS").unwrap() as u16;
    let (_, _, _, value, refusal) = param(&rig.send(&ToFc::ParamSet { index: fs, value: 80.0 }, 2_000));
    assert_eq!((value, refusal), (80.0, 0));
    assert_eq!(rig.fc.settings().failsafe_timeout_ms, 80);
    // No such parameter.
    let (_, _, id, value, refusal) = param(&rig.send(&ToFc::ParamRead { index: 999 }, 2_000));
    assert!(value.is_nan() && refusal == 1 && id == [0; 16]);
}

/// The gains are parameters: `PD_ROLL_P`/`PD_ROLL_D` are the angular
/// acceleration a roll error commands (checked against the thesis' torque
/// `l·U2 = Ix·φ̈` at zero rates of the other axes), and an LQR weight
/// multiplier re-designs the LQR (a heavier position weight answers a
/// position error harder). Both only before the first step; out of range
/// refused.
#[test]
fn gains_and_weights_are_parameters_that_redesign_the_controller() {
    let set = |rig: &mut Rig, name: &[u8], value: f32, now_us: u64| -> (f32, u8) {
        let index = params::index_of(name).unwrap() as u16;
        match rig.send(&ToFc::ParamSet { index, value }, now_us)[..] {
            [FromFc::Param { value, refusal, .. }] => (value, refusal),
            ref other => panic!("{other:?}"),
        }
    };
    let first_u = |rig: &mut Rig, state: [f32; 13]| -> [f32; 4] {
        match rig.send(
            &ToFc::Sensor {
                seq: 1,
                t_us: 2_000,
                state,
            },
            2_000,
        )[..]
        {
            [FromFc::Actuator { u, .. }, ..] => u,
            ref other => panic!("{other:?}"),
        }
    };
    // PD Euler, roll gains 300 (rad/s²)/rad and 20 (rad/s²)/(rad/s).
    let mut rig = Rig::new();
    rig.open();
    assert_eq!(set(&mut rig, b"CTL_ID", 0.0, 0), (0.0, 0));
    assert_eq!(set(&mut rig, b"PD_ROLL_P", 300.0, 0), (300.0, 0));
    assert_eq!(set(&mut rig, b"PD_ROLL_D", 20.0, 0), (20.0, 0));
    // Negative gains, absurd multipliers: refused (out of range), kept.
    assert_eq!(set(&mut rig, b"PD_ROLL_P", -1.0, 0), (300.0, 2));
    assert_eq!(set(&mut rig, b"LQR_W_POS", 0.0, 0), (1.0, 2));
    assert_eq!(set(&mut rig, b"MPC_W_U", f32::NAN, 0), (1.0, 2));
    // At the set-point, rolled 0.05 rad and rolling at 0.2 rad/s.
    let mut s = hover_state();
    let half = 0.025f32;
    s[6..10].copy_from_slice(&[libm::cosf(half), libm::sinf(half), 0.0, 0.0]);
    s[10] = 0.2;
    let u = first_u(&mut rig, s);
    let p = rig.fc.vehicle();
    let roll_accel = p.arm_m * u[1] / p.inertia_kgm2[0];
    let want = -300.0 * 0.05 - 20.0 * 0.2;
    assert!((roll_accel - want).abs() < 1e-3 * want.abs(), "{roll_accel} vs {want}");
    // In flight: a gain change re-designs, refused.
    assert_eq!(set(&mut rig, b"PD_ROLL_P", 200.0, 2_000), (300.0, 7));

    // The LQR (quaternion, the boot controller): 10 cm north of the
    // set-point, the pitch command for weights ×1 and position ×4.
    let pitch_cmd = |w: f32| {
        let mut rig = Rig::new();
        rig.open();
        assert_eq!(set(&mut rig, b"LQR_W_POS", w, 0), (w, 0));
        let mut s = hover_state();
        s[0] = 0.1;
        first_u(&mut rig, s)[2]
    };
    let (u1, u4) = (pitch_cmd(1.0), pitch_cmd(4.0));
    // Nose down to go back south… the answer grows with the weight
    // (roughly with its square root for a position-dominated gain).
    assert!(u1 != 0.0 && u4.signum() == u1.signum(), "{u1} {u4}");
    assert!(u4.abs() > 1.3 * u1.abs(), "{u1} {u4}");
}

/// `MOT_FRAME` selects each standard layout by its number, reads back what
/// was written, and refuses a number no layout has (the settings unchanged).
#[test]
fn every_motor_layout_is_a_mot_frame_value() {
    use params::{Airframe, Refusal, Settings};
    let i = params::index_of(b"MOT_FRAME").unwrap();
    let mut s = Settings::os4();
    s.hub_m = 0.043;
    for (n, want) in Airframe::ALL.iter().enumerate() {
        let next = params::write(&s, i, n as f32).unwrap();
        assert_eq!(next.airframe, *want);
        assert_eq!((params::PARAMS[i].get)(&next), n as f32);
        assert!(next.mixer().is_ok(), "{want:?} mixes");
    }
    assert_eq!(
        params::write(&s, i, 5.0).unwrap_err(),
        Refusal::Range { lo: 0.0, hi: 4.0 }
    );
    assert_eq!(params::write(&s, i, 1.5).unwrap_err(), Refusal::NotInteger);
}

/// Each parameter's declared type is what its setter takes: an integer
/// parameter (the ones CRTP's TOC declares `uint8_t`/`uint16_t`) holds a
/// whole number its type can carry, refuses a fraction (`CTL_ID` = 5.05 is
/// not taken as 5) and refuses one past its type's range; a real one
/// takes a fraction.
#[test]
fn every_parameter_takes_what_its_type_says() {
    use params::{ParamType, Refusal, Settings, PARAMS};
    let s = Settings::os4();
    let mut integers = 0;
    for (i, p) in PARAMS.iter().enumerate() {
        let v = (p.get)(&s);
        match p.ty {
            ParamType::F32 => {
                let r = params::write(&s, i, v * 1.001 + 1e-4);
                assert_ne!(r.err(), Some(Refusal::NotInteger), "{} is a real", p.id);
            }
            ty => {
                integers += 1;
                assert!(v.fract() == 0.0 && (0.0..=ty.max()).contains(&v), "{} = {v}", p.id);
                // A fraction inside its range (above 0, below the value
                // in force where it can be).
                let frac = if v >= 1.0 { v - 0.05 } else { v + 0.05 };
                assert_eq!(params::write(&s, i, frac).unwrap_err(), Refusal::NotInteger, "{}", p.id);
                assert!(params::write(&s, i, ty.max() + 1.0).is_err(), "{} past {ty:?}", p.id);
            }
        }
    }
    assert_eq!(integers, 11);
    let ctl = params::index_of(b"CTL_ID").unwrap();
    assert_eq!(PARAMS[ctl].ty, ParamType::U8);
}

/// The one table: every name is unique and fits MAVLink's 16 bytes; CRTP
/// serves the first [`params::CRTP_PARAMS`] under their split names and
/// none of the automatic modes' (PX4's names, MAVLink only); a mode's
/// setting refuses a value out of its range, NaN included, and keeps the
/// one in force.
#[test]
fn one_parameter_table_names_each_for_every_protocol_and_checks_the_modes() {
    use params::{Refusal, Settings, CRTP_PARAMS, PARAMS};
    for (i, p) in PARAMS.iter().enumerate() {
        assert!(p.mavlink_name().len() <= 16, "{}", p.id);
        assert_eq!(params::index_of(p.mavlink_name().as_bytes()), Some(i), "{}", p.id);
        assert_eq!(p.crtp_name().is_some(), i < CRTP_PARAMS, "{}", p.id);
    }
    assert_eq!(
        PARAMS[params::index_of(b"VEH_MASS").unwrap()].crtp_name(),
        Some(("VEH", "MASS"))
    );
    // The Crazyflie's names, beside the table's: CTL_ID and the PD's
    // attitude gains (the Crazyflie's `stabilizer.controller` and
    // `pid_attitude` group).
    let aliased: Vec<_> = params::CRTP_ALIASED
        .iter()
        .map(|&i| (PARAMS[i].id, PARAMS[i].crtp_alias().unwrap()))
        .collect();
    assert_eq!(
        aliased,
        [
            ("CTL_ID", ("stabilizer", "controller")),
            ("PD_ROLL_P", ("pid_attitude", "roll_kp")),
            ("PD_ROLL_D", ("pid_attitude", "roll_kd")),
            ("PD_PITCH_P", ("pid_attitude", "pitch_kp")),
            ("PD_PITCH_D", ("pid_attitude", "pitch_kd")),
            ("PD_YAW_P", ("pid_attitude", "yaw_kp")),
            ("PD_YAW_D", ("pid_attitude", "yaw_kd")),
        ]
    );
    assert_eq!(params::crtp_params().len(), CRTP_PARAMS);
    // The modes' settings and SYS_FAILURE_EN: the twelve after CRTP's,
    // unknown to it.
    let modes = PARAMS.len() - CRTP_PARAMS;
    assert_eq!((CRTP_PARAMS, modes), (52, 12));
    let s = Settings::os4();
    let i = params::index_of(b"MIS_TAKEOFF_ALT\0").unwrap();
    assert_eq!(i, CRTP_PARAMS);
    assert_eq!(params::write(&s, i, 1.5).unwrap().nav.takeoff_alt_m, 1.5);
    let range = Refusal::Range { lo: 0.2, hi: 100.0 };
    assert_eq!(params::write(&s, i, -1.0), Err(range));
    assert_eq!(params::write(&s, i, f32::NAN), Err(range));
    // Each default is within its range: written back as it is, taken.
    for (k, p) in PARAMS.iter().enumerate().skip(CRTP_PARAMS) {
        assert_eq!(params::write(&s, k, (p.get)(&s)), Ok(s), "{}", p.id);
    }
    assert_eq!(params::index_of(b"NOPE"), None);
}
