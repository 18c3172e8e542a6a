//! PX4's numbers for the flight stack's modes ([`fc_loop::modes`], which
//! decides what each flies), so that a ground station's PX4 mode table
//! (MAVSDK's, QGroundControl's, MAVProxy's) applies unchanged: the mode is
//! `HEARTBEAT.custom_mode` in PX4's encoding (`px4_custom_mode.h`: the main
//! mode in bits 16–23, the sub mode in bits 24–31) and is asked for with
//! `MAV_CMD_DO_SET_MODE` (`param1` `MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`,
//! `param2` the main mode, `param3` the sub mode). Without that flag
//! `param1` alone is read as PX4 reads it ([`Px4Mode::from_base_mode`]).
//! The automatic modes' settings are PX4's parameters, in the flight
//! stack's one table ([`fc_loop::params::PARAMS`]).
//!
//! | mode | PX4 (main, sub) |
//! |---|---|
//! | Position | POSCTL (3, 0) |
//! | Hold | AUTO (4) LOITER (3) |
//! | Takeoff | AUTO TAKEOFF (2) |
//! | Land | AUTO LAND (6) |
//! | Return | AUTO RTL (5) |
//! | Offboard | OFFBOARD (6, 0) |
//! | Mission | AUTO MISSION (4) |

use mavlink::dialects::common::MavModeFlag;

/// PX4's main and sub mode numbers (`px4_custom_mode.h`).
pub mod px4 {
    /// Position control.
    pub const MAIN_POSCTL: u8 = 3;
    /// The automatic modes (their sub mode says which).
    pub const MAIN_AUTO: u8 = 4;
    /// Offboard.
    pub const MAIN_OFFBOARD: u8 = 6;
    /// AUTO: takeoff.
    pub const SUB_TAKEOFF: u8 = 2;
    /// AUTO: loiter (MAVSDK's and QGroundControl's "Hold").
    pub const SUB_LOITER: u8 = 3;
    /// AUTO: mission.
    pub const SUB_MISSION: u8 = 4;
    /// AUTO: return to launch.
    pub const SUB_RTL: u8 = 5;
    /// AUTO: land.
    pub const SUB_LAND: u8 = 6;
}

/// PX4's encoding of the flight stack's modes ([`FlightMode`]): the
/// numbers a PX4 ground station sends and reads.
pub trait Px4Mode: Sized {
    /// PX4's (main, sub) mode.
    fn px4(self) -> (u8, u8);
    /// `HEARTBEAT.custom_mode` in PX4's encoding.
    fn custom_mode(self) -> u32;
    /// The mode PX4's (main, sub) names, if this vehicle flies it (the
    /// sub mode counts only under AUTO, as in PX4).
    fn from_px4(main: u8, sub: u8) -> Option<Self>;
    /// The mode a `DO_SET_MODE` without `MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`
    /// asks for, as PX4's commander reads its `base_mode`: AUTO is the
    /// mission, manual input with GUIDED is position control. Manual input
    /// alone (PX4's manual or stabilized) is not flown here.
    fn from_base_mode(base: MavModeFlag) -> Option<Self>;
}

impl Px4Mode for FlightMode {
    fn px4(self) -> (u8, u8) {
        use px4::*;
        match self {
            FlightMode::Position => (MAIN_POSCTL, 0),
            FlightMode::Hold => (MAIN_AUTO, SUB_LOITER),
            FlightMode::Takeoff => (MAIN_AUTO, SUB_TAKEOFF),
            FlightMode::Land => (MAIN_AUTO, SUB_LAND),
            FlightMode::Return => (MAIN_AUTO, SUB_RTL),
            FlightMode::Offboard => (MAIN_OFFBOARD, 0),
            FlightMode::Mission => (MAIN_AUTO, SUB_MISSION),
        }
    }

    fn custom_mode(self) -> u32 {
        let (main, sub) = self.px4();
        (u32::from(main) << 16) | (u32::from(sub) << 24)
    }

    fn from_px4(main: u8, sub: u8) -> Option<Self> {
        use px4::*;
        match (main, sub) {
            (MAIN_POSCTL, _) => Some(FlightMode::Position),
            (MAIN_OFFBOARD, _) => Some(FlightMode::Offboard),
            // AUTO without a sub mode is PX4's mission.
            (MAIN_AUTO, 0) => Some(FlightMode::Mission),
            (MAIN_AUTO, SUB_LOITER) => Some(FlightMode::Hold),
            (MAIN_AUTO, SUB_TAKEOFF) => Some(FlightMode::Takeoff),
            (MAIN_AUTO, SUB_LAND) => Some(FlightMode::Land),
            (MAIN_AUTO, SUB_RTL) => Some(FlightMode::Return),
            (MAIN_AUTO, SUB_MISSION) => Some(FlightMode::Mission),
            _ => None,
        }
    }

    fn from_base_mode(base: MavModeFlag) -> Option<Self> {
        if base.contains(MavModeFlag::MAV_MODE_FLAG_AUTO_ENABLED) {
            Some(FlightMode::Mission)
        } else if base
            .contains(MavModeFlag::MAV_MODE_FLAG_MANUAL_INPUT_ENABLED | MavModeFlag::MAV_MODE_FLAG_GUIDED_ENABLED)
        {
            Some(FlightMode::Position)
        } else {
            None
        }
    }
}

// An automatic mode's legs are planned by the flight stack's commander;
// the modes are the flight stack's.
pub use fc_loop::commander::{leg_duration_s, Legs, Route};
pub use fc_loop::modes::{joystick_velocity, FlightMode, NavSettings};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_encode_as_px4_and_decode_back() {
        // px4_custom_mode.h: main mode in byte 2, sub mode in byte 3.
        assert_eq!(FlightMode::Position.custom_mode(), 0x0003_0000);
        assert_eq!(FlightMode::Offboard.custom_mode(), 0x0006_0000);
        assert_eq!(FlightMode::Hold.custom_mode(), 0x0304_0000);
        assert_eq!(FlightMode::Takeoff.custom_mode(), 0x0204_0000);
        assert_eq!(FlightMode::Mission.custom_mode(), 0x0404_0000);
        assert_eq!(FlightMode::Return.custom_mode(), 0x0504_0000);
        assert_eq!(FlightMode::Land.custom_mode(), 0x0604_0000);
        for m in FlightMode::ALL {
            let (main, sub) = m.px4();
            assert_eq!(FlightMode::from_px4(main, sub), Some(m));
            let c = m.custom_mode().to_le_bytes();
            assert_eq!((c[2], c[3]), (main, sub));
        }
        // Manual, AUTO READY and follow-me are not flown here.
        assert_eq!(FlightMode::from_px4(1, 0), None);
        assert_eq!(FlightMode::from_px4(4, 1), None);
        assert_eq!(FlightMode::from_px4(4, 8), None);
        // AUTO alone: PX4 flies the mission.
        assert_eq!(FlightMode::from_px4(4, 0), Some(FlightMode::Mission));
    }

    #[test]
    fn a_base_mode_alone_is_read_as_px4s_commander_reads_it() {
        // MAV_MODE values (common.xml): AUTO_DISARMED 92 and GUIDED_DISARMED
        // 88 carry AUTO; MANUAL_DISARMED 64 and STABILIZE_DISARMED 80 are
        // manual input without GUIDED; PREFLIGHT 0 is nothing.
        let base = |b: u8| FlightMode::from_base_mode(MavModeFlag::from_bits_truncate(b));
        assert_eq!(base(92), Some(FlightMode::Mission));
        assert_eq!(base(4), Some(FlightMode::Mission));
        assert_eq!(base(64 | 8), Some(FlightMode::Position));
        assert_eq!(base(64), None);
        assert_eq!(base(80), None);
        assert_eq!(base(0), None);
    }
}
