//! The automatic modes' settings and the joystick's scale.

use nalgebra::Vector3;

/// The automatic modes' settings (PX4's parameter names beside each). The
/// defaults are PX4's where a room-sized vehicle can fly them, and smaller
/// where it cannot (PX4's are for an outdoor multicopter: a 60 m return
/// height, 5 m/s cruise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavSettings {
    /// `MIS_TAKEOFF_ALT`: takeoff height above home, m (PX4: 2.5).
    pub takeoff_alt_m: f32,
    /// `RTL_RETURN_ALT`: the least height a return flies home at, m (PX4: 60).
    pub rtl_alt_m: f32,
    /// `MPC_XY_CRUISE`: horizontal speed of the automatic modes, m/s (PX4: 5).
    pub cruise_mps: f32,
    /// `MPC_Z_V_AUTO_UP`: climb speed, m/s (PX4: 3).
    pub climb_mps: f32,
    /// `MPC_LAND_SPEED`: descent speed of a landing, m/s (PX4: 0.7).
    pub land_mps: f32,
    /// `COM_OF_LOSS_T`: set-points silent this long end Offboard, s (PX4: 1).
    pub offboard_loss_s: f32,
    /// `NAV_ACC_RAD`: a mission waypoint is reached within this, m, unless
    /// the item gives its own (PX4: 10, for outdoor flight).
    pub acc_rad_m: f32,
    /// `MPC_VEL_MANUAL`: horizontal speed of a full joystick deflection in
    /// Position mode, m/s (PX4: 10).
    pub manual_mps: f32,
    /// `MPC_Z_VEL_MAX_UP`: vertical speed of full throttle up or down in
    /// Position mode, m/s (PX4: 3).
    pub manual_z_mps: f32,
    /// `MPC_MAN_Y_MAX`: heading rate of a full yaw deflection, °/s (PX4: 150).
    pub manual_yaw_dps: f32,
    /// `COM_RC_LOSS_T`: a joystick silent this long is lost (then Land), s (PX4: 0.5).
    pub manual_loss_s: f32,
    /// `SYS_FAILURE_EN`: failure injection (`MAV_CMD_INJECT_FAILURE`)
    /// obeyed; off, every injection is denied (PX4: off).
    pub failure_injection: bool,
}

impl Default for NavSettings {
    fn default() -> Self {
        Self {
            takeoff_alt_m: 2.5,
            rtl_alt_m: 2.0,
            cruise_mps: 1.0,
            climb_mps: 0.5,
            land_mps: 0.5,
            offboard_loss_s: 1.0,
            acc_rad_m: 0.1,
            manual_mps: 1.0,
            manual_z_mps: 0.5,
            manual_yaw_dps: 60.0,
            manual_loss_s: 0.5,
            failure_injection: false,
        }
    }
}

/// A joystick's deflection in [−1000, 1000] (x forward, y right, r yaw;
/// z throttle in [0, 1000], 500 centred: MAVLink's `MANUAL_CONTROL` scale)
/// as PX4's Position mode reads it: the set-point's velocity (north, east,
/// down, m/s, turned by heading `yaw_rad`) and heading rate (rad/s), each
/// axis with a 5 % dead band and full scale at the [`NavSettings`]' speeds.
pub fn joystick_velocity(nav: &NavSettings, x: i16, y: i16, z: i16, r: i16, yaw_rad: f32) -> (Vector3<f32>, f32) {
    let axis = |v: i16, centre: f32, half: f32| {
        let a = ((f32::from(v) - centre) / half).clamp(-1.0, 1.0);
        if a.abs() < 0.05 {
            0.0
        } else {
            (a - 0.05 * a.signum()) / 0.95
        }
    };
    let (fwd, right) = (
        axis(x, 0.0, 1000.0) * nav.manual_mps,
        axis(y, 0.0, 1000.0) * nav.manual_mps,
    );
    let up = axis(z, 500.0, 500.0) * nav.manual_z_mps;
    let (s, c) = (libm::sinf(yaw_rad), libm::cosf(yaw_rad));
    let v = Vector3::new(c * fwd - s * right, s * fwd + c * right, -up);
    (v, axis(r, 0.0, 1000.0) * nav.manual_yaw_dps.to_radians())
}
