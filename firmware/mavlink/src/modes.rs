//! PX4's numbers for the flight stack's modes ([`fc_loop::modes`], which
//! decides what each flies), so that a ground station's PX4 mode table
//! (MAVSDK's, QGroundControl's, MAVProxy's) applies unchanged: the mode is
//! `HEARTBEAT.custom_mode` in PX4's encoding (`px4_custom_mode.h`: the main
//! mode in bits 16–23, the sub mode in bits 24–31) and is asked for with
//! `MAV_CMD_DO_SET_MODE` (`param1` `MAV_MODE_FLAG_CUSTOM_MODE_ENABLED`,
//! `param2` the main mode, `param3` the sub mode). Without that flag
//! `param1` alone is read as PX4 reads it ([`Px4Mode::from_base_mode`]).
//! The automatic modes' settings are PX4's parameters here
//! ([`NAV_PARAMS`]).
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

use crate::params::Refusal;
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

/// One of [`NavSettings`]' parameters.
#[derive(Clone, Copy)]
pub struct NavParam {
    /// Its PX4 name.
    pub id: &'static str,
    /// What it is, with its unit.
    pub doc: &'static str,
    /// Accepted range.
    pub range: (f32, f32),
    /// Its value.
    pub get: fn(&NavSettings) -> f32,
    /// Where it is written.
    pub field: fn(&mut NavSettings) -> &mut f32,
}

impl core::fmt::Debug for NavParam {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("NavParam").field("id", &self.id).finish()
    }
}

macro_rules! nav {
    ($id:literal, $doc:literal, $lo:expr, $hi:expr, $f:ident) => {
        NavParam {
            id: $id,
            doc: $doc,
            range: ($lo, $hi),
            get: |s| s.$f,
            field: |s| &mut s.$f,
        }
    };
}

/// The automatic modes' parameters, served after the flight loop's
/// ([`crate::params::PARAMS`]) in `param_index` order.
pub const NAV_PARAMS: [NavParam; 11] = [
    nav!(
        "MIS_TAKEOFF_ALT",
        "takeoff height above home, m",
        0.2,
        100.0,
        takeoff_alt_m
    ),
    nav!(
        "RTL_RETURN_ALT",
        "least height of a return home, m",
        0.2,
        500.0,
        rtl_alt_m
    ),
    nav!(
        "MPC_XY_CRUISE",
        "horizontal speed of the automatic modes, m/s",
        0.1,
        20.0,
        cruise_mps
    ),
    nav!(
        "MPC_Z_V_AUTO_UP",
        "climb speed of the automatic modes, m/s",
        0.1,
        8.0,
        climb_mps
    ),
    nav!("MPC_LAND_SPEED", "descent speed of a landing, m/s", 0.1, 4.0, land_mps),
    nav!(
        "COM_OF_LOSS_T",
        "offboard set-points silent this long end offboard, s",
        0.1,
        60.0,
        offboard_loss_s
    ),
    nav!(
        "NAV_ACC_RAD",
        "a mission waypoint is reached within this, m",
        0.01,
        100.0,
        acc_rad_m
    ),
    nav!(
        "MPC_VEL_MANUAL",
        "horizontal speed of a full joystick deflection, m/s",
        0.1,
        20.0,
        manual_mps
    ),
    nav!(
        "MPC_Z_VEL_MAX_UP",
        "vertical speed of full joystick throttle, m/s",
        0.1,
        8.0,
        manual_z_mps
    ),
    nav!(
        "MPC_MAN_Y_MAX",
        "heading rate of a full yaw deflection, deg/s",
        1.0,
        400.0,
        manual_yaw_dps
    ),
    nav!(
        "COM_RC_LOSS_T",
        "a joystick silent this long is lost (then land), s",
        0.1,
        60.0,
        manual_loss_s
    ),
];

/// Writes parameter `index` of [`NAV_PARAMS`] in `nav`: refused outside
/// its range.
pub fn set_nav(nav: &mut NavSettings, index: usize, value: f32) -> Result<(), Refusal> {
    let p = NAV_PARAMS.get(index).ok_or(Refusal::Unknown)?;
    let (lo, hi) = p.range;
    if !(value.is_finite() && (lo..=hi).contains(&value)) {
        return Err(Refusal::Range { lo, hi });
    }
    *(p.field)(nav) = value;
    Ok(())
}

/// The index in [`NAV_PARAMS`] of the parameter named `id` (NUL-padded).
pub fn nav_index_of(id: &[u8]) -> Option<usize> {
    let len = id.iter().position(|&b| b == 0).unwrap_or(id.len());
    NAV_PARAMS.iter().position(|p| p.id.as_bytes() == &id[..len])
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

    #[test]
    fn nav_parameters_are_named_as_px4_and_checked() {
        let mut s = NavSettings::default();
        let i = nav_index_of(b"MIS_TAKEOFF_ALT\0").unwrap();
        set_nav(&mut s, i, 1.5).unwrap();
        assert_eq!(s.takeoff_alt_m, 1.5);
        assert_eq!(set_nav(&mut s, i, -1.0), Err(Refusal::Range { lo: 0.2, hi: 100.0 }));
        assert_eq!(set_nav(&mut s, i, f32::NAN), Err(Refusal::Range { lo: 0.2, hi: 100.0 }));
        assert_eq!(s.takeoff_alt_m, 1.5);
        for (k, p) in NAV_PARAMS.iter().enumerate() {
            assert!(p.id.len() <= 16);
            assert_eq!(nav_index_of(p.id.as_bytes()), Some(k));
            let (lo, hi) = p.range;
            assert!((lo..=hi).contains(&(p.get)(&NavSettings::default())), "{}", p.id);
        }
        assert_eq!(nav_index_of(b"NOPE"), None);
    }
}
