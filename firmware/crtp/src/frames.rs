//! The Crazyflie's world frame and the core's NED.
//!
//! The Crazyflie flies in a right-handed world frame with x forward, y
//! left and z up (its body frame is x forward, y left, z up too). The core
//! flies NED with body FRD. With the Crazyflie's x along north:
//! north = x, east = −y, down = −z, and a heading ψ (NED, clockwise from
//! north seen from above) is the Crazyflie's yaw negated.

use nalgebra::Vector3;

/// A Crazyflie world vector (x forward, y left, z up) in NED.
pub fn ned_from_cf(v: [f32; 3]) -> Vector3<f32> {
    Vector3::new(v[0], -v[1], -v[2])
}

/// A NED vector in the Crazyflie's world frame (x forward, y left, z up).
pub fn cf_from_ned(v: &Vector3<f32>) -> [f32; 3] {
    [v[0], -v[1], -v[2]]
}

/// A Crazyflie yaw (counter-clockwise from x seen from above) as a NED
/// heading, and back: the same map both ways, rad.
pub fn heading_from_cf_yaw(yaw_rad: f32) -> f32 {
    -yaw_rad
}

/// The Crazyflie's yaw of a body whose attitude quaternion (x, y, z, w;
/// body → world, both frames x forward, y left, z up) is `q`, rad.
pub fn cf_yaw_of_quat(qx: f32, qy: f32, qz: f32, qw: f32) -> f32 {
    libm::atan2f(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_ahead_left_and_up_is_north_west_and_negative_down() {
        let n = ned_from_cf([1.0, 2.0, 3.0]);
        assert_eq!(n, Vector3::new(1.0, -2.0, -3.0));
        assert_eq!(cf_from_ned(&n), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn a_quarter_turn_left_is_a_heading_of_minus_ninety_degrees() {
        // Rotation of +90° about z up: q = (0, 0, sin 45°, cos 45°).
        let s = core::f32::consts::FRAC_1_SQRT_2;
        let yaw = cf_yaw_of_quat(0.0, 0.0, s, s);
        assert!((yaw - core::f32::consts::FRAC_PI_2).abs() < 1e-6);
        assert!((heading_from_cf_yaw(yaw) + core::f32::consts::FRAC_PI_2).abs() < 1e-6);
    }
}
