//! The modes against analytic truth (the joystick's scale) and their
//! refusals; their flights are tested through MAVLink, whose ground
//! station commands them (fc-mavlink's vehicle tests).

use super::*;
use crate::FcConfig;

#[test]
fn the_joystick_maps_as_px4s_position_mode() {
    let nav = NavSettings::default();
    // Centred (throttle at 500) and inside the dead band: nothing.
    assert_eq!(joystick_velocity(&nav, 40, -40, 520, 0, 0.0), (Vector3::zeros(), 0.0));
    // Full forward, heading north: 1 m/s north; heading east: east.
    let (v, _) = joystick_velocity(&nav, 1000, 0, 500, 0, 0.0);
    assert!((v - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-6, "{v}");
    let (v, _) = joystick_velocity(&nav, 1000, 0, 500, 0, core::f32::consts::FRAC_PI_2);
    assert!((v - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-6, "{v}");
    // Full right and full throttle: east and up; full yaw: 60 °/s.
    let (v, r) = joystick_velocity(&nav, 0, 1000, 1000, 1000, 0.0);
    assert!((v - Vector3::new(0.0, 1.0, -0.5)).norm() < 1e-6 && (r - 60f32.to_radians()).abs() < 1e-6);
    // Half way out of the dead band is half speed, continuously from 0 at its edge.
    let (v, _) = joystick_velocity(&nav, 525, 0, 500, 0, 0.0);
    assert!((v[0] - 0.5).abs() < 1e-6, "{v}");
    let (v, _) = joystick_velocity(&nav, -32768, 0, 0, 0, 0.0);
    assert!((v - Vector3::new(-1.0, 0.0, 0.5)).norm() < 1e-6, "clamped: {v}");
}

/// A mission of `n` items that each hold 1 s.
struct Delays {
    n: usize,
    current: u16,
}

impl MissionItems for Delays {
    fn len(&self) -> usize {
        self.n
    }
    fn current(&self) -> u16 {
        self.current
    }
    fn set_current(&mut self, seq: u16) {
        self.current = seq;
    }
    fn action(&self, seq: u16, _: f32) -> Option<Result<MissionAction, ()>> {
        (usize::from(seq) < self.n).then_some(Ok(MissionAction::Delay { s: 1.0 }))
    }
}

#[test]
fn a_mode_that_cannot_be_flown_is_refused_with_its_reason_and_nothing_changes() {
    let mut flight = crate::FlightLoop::new(FcConfig::default()).unwrap();
    let mut m = ModeCommander::new();
    let mut none = Delays { n: 0, current: 0 };
    let mut two = Delays { n: 2, current: 0 };
    let nan = f32::NAN;
    let boot_sp = *flight.setpoint();
    // Nothing streamed: no Offboard, armed or not.
    assert_eq!(
        m.set_mode(FlightMode::Offboard, 0, nan, &mut flight, &mut none),
        Err(ModeRefusal::NotStreaming)
    );
    assert_eq!(
        m.set_mode(FlightMode::Mission, 0, nan, &mut flight, &mut none),
        Err(ModeRefusal::NoMission)
    );
    for mode in [
        FlightMode::Mission,
        FlightMode::Takeoff,
        FlightMode::Land,
        FlightMode::Return,
    ] {
        assert_eq!(
            m.set_mode(mode, 0, nan, &mut flight, &mut two),
            Err(ModeRefusal::Disarmed),
            "{mode}"
        );
    }
    assert_eq!(m.mode(), FlightMode::Position);
    // A stream older than COM_OF_LOSS_T is no stream.
    m.offboard(Setpoint::hold(Vector3::new(1.0, 0.0, -2.0), 0.0), 0);
    assert_eq!(
        m.set_mode(FlightMode::Offboard, 1_000_001, nan, &mut flight, &mut none),
        Err(ModeRefusal::NotStreaming)
    );
    assert_eq!(
        m.set_mode(FlightMode::Offboard, 1_000_000, nan, &mut flight, &mut none),
        Ok(())
    );
    // Disarmed, a stream is kept, not flown; no step flies anything.
    assert_eq!(*flight.setpoint(), boot_sp);
    let mut said = 0;
    let r: Result<(), ()> = m.fly(5_000_000, 0.001, &mut flight, &mut two, &mut |_| {
        said += 1;
        Ok(())
    });
    assert_eq!((r, said, m.mode()), (Ok(()), 0, FlightMode::Offboard));
    // Arming needs an estimate: none yet.
    let (lp, ctrl) = flight.split();
    assert!(m.arm(lp, ctrl, true).is_err());
    assert!(!m.armed());
}

#[test]
fn events_read_as_the_ground_station_reads_them() {
    assert_eq!(
        format!("{}", ModeEvent::ItemNotFlyable(3)),
        "mission item 3 cannot be flown: hold"
    );
    assert_eq!(format!("{}", ModeRefusal::NotStreaming), "no set-points streaming");
    assert!(ModeEvent::GroundStationLost.is_failsafe() && !ModeEvent::OffboardLost.is_failsafe());
}
