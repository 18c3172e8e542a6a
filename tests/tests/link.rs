//! The same flight through the three paths that need no emulator:
//! in-process, framed (the core behind the wire protocol) and TCP to
//! `serve`, and `serve` surviving hostile clients.

use fc_core::control::{Family, Preset};
use sil_host::flight::{fly, fly_target, FlightConfig, Target};
use sil_host::{AttitudeForm, Scenario, ScenarioKind};
use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::time::Duration;

fn cases() -> Vec<FlightConfig> {
    let mut lqr = FlightConfig::new(
        Family::Lqr,
        AttitudeForm::Quaternion,
        Scenario::default_for(ScenarioKind::Setpoint),
    );
    lqr.scenario.duration_s = 6.0;
    let mut mpc = FlightConfig::new(
        Family::Mpc,
        AttitudeForm::Euler,
        Scenario::default_for(ScenarioKind::Helix),
    );
    mpc.spec.preset = Preset::Project;
    mpc.scenario.duration_s = 6.0;
    mpc.disturbance = "wind".parse().unwrap();
    let mut pd = FlightConfig::new(
        Family::Pd,
        AttitudeForm::Euler,
        Scenario::default_for(ScenarioKind::Circle),
    );
    pd.scenario.duration_s = 4.0;
    vec![lqr, mpc, pd]
}

#[test]
fn framed_flight_is_identical_to_in_process() {
    for cfg in cases() {
        let a = fly(&cfg).unwrap();
        let b = fly_target(&cfg, &Target::Framed).unwrap();
        // Same f32 inputs, same code: the trajectories agree exactly.
        assert_eq!(a.rows.len(), b.rows.len());
        for (ra, rb) in a.rows.iter().zip(&b.rows) {
            assert_eq!(ra, rb, "{:?} {:?}", cfg.spec.family, cfg.scenario.kind);
        }
    }
}

#[test]
fn serve_survives_hostile_clients_then_flies() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || sil_host::link::serve(listener, Duration::from_secs(2), Some(6), false));
    let hostile: Vec<Vec<u8>> = vec![
        (0..5000u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect(), // random bytes
        vec![0u8; 100],                                                           // empty frames
        {
            let mut v = vec![0x42u8; 10_000];
            v.push(0);
            v
        }, // oversized
        vec![0x05, 0x01, 0x02, 0x03, 0x04, 0x00, 0x03, 0xff, 0xff, 0x00],         // framed nonsense
        vec![],                                                                   // connect and hang up
    ];
    for bytes in hostile {
        let mut s = TcpStream::connect(&addr).unwrap();
        let _ = s.write_all(&bytes);
        drop(s);
    }
    let cfg = &cases()[0];
    let want = fly(cfg).unwrap();
    let got = fly_target(cfg, &Target::Tcp(addr)).unwrap();
    assert_eq!(want.rows, got.rows);
    assert!(server.join().unwrap().is_ok());
}
