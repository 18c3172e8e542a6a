//! One land detector for every protocol (PX4's, simplified): a vehicle
//! coming down to the ground is on it once its estimate is within
//! [`LANDED_M`] of that ground and slower than [`LANDED_MPS`] vertically.
//!
//! When a vehicle is coming down is its commander's to say: on CRTP, a
//! landing segment (the high-level commander's `land`, the failsafe
//! descent) that has reached its goal; on MAVLink, the Land mode or the
//! descent of a Return or a mission's landing. The ground is where that
//! descent ends: the segment's goal height (CRTP), the height the vehicle
//! armed at (MAVLink).

use fc_core::control::StateEstimate;

/// Below this fraction of hover thrust, a landing vehicle is pressing on
/// the ground (PX4's land detector's low-thrust test): no descent flies
/// on so little.
pub const GROUND_THRUST: f32 = 0.3;

/// That long below [`GROUND_THRUST`], a landing vehicle is on the ground
/// whatever its estimate says (a vehicle without a height reference, whose
/// dead-reckoned height drifts), µs.
pub const GROUND_CONTACT_US: u64 = 1_000_000;

/// Ground contact by thrust (see [`GROUND_THRUST`]): a landing vehicle
/// whose collective thrust has stayed below it for [`GROUND_CONTACT_US`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GroundContact {
    since_us: Option<u64>,
}

impl GroundContact {
    /// No contact yet.
    pub const fn new() -> Self {
        Self { since_us: None }
    }

    /// A landing step at `t_us` with collective thrust `thrust_n` (hover:
    /// `hover_n`), N: whether it has pressed on the ground long enough. A
    /// NaN thrust is no contact.
    pub fn step(&mut self, t_us: u64, thrust_n: f32, hover_n: f32) -> bool {
        if thrust_n < GROUND_THRUST * hover_n {
            let since = *self.since_us.get_or_insert(t_us);
            t_us.saturating_sub(since) >= GROUND_CONTACT_US
        } else {
            self.since_us = None;
            false
        }
    }

    /// Not landing: forgotten.
    pub fn reset(&mut self) {
        self.since_us = None;
    }
}

/// Within this height of the ground it comes down to, a landing vehicle is
/// on it, m.
pub const LANDED_M: f32 = 0.05;

/// Slower than this vertically (estimated), a landing vehicle near the
/// ground is on it, m/s.
pub const LANDED_MPS: f32 = 0.2;

/// Whether `est` is on the ground whose NED down coordinate is
/// `ground_down_m`, m: within [`LANDED_M`] of it and slower than
/// [`LANDED_MPS`] vertically. A NaN anywhere in the test is not landed.
pub fn on_ground(est: &StateEstimate<f32>, ground_down_m: f32) -> bool {
    (est.pos_ned_m[2] - ground_down_m).abs() < LANDED_M && est.vel_ned_mps[2].abs() < LANDED_MPS
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Vector3, Vector4};

    fn at(down_m: f32, vd_mps: f32) -> StateEstimate<f32> {
        StateEstimate {
            pos_ned_m: Vector3::new(0.3, -0.2, down_m),
            vel_ned_mps: Vector3::new(0.0, 0.0, vd_mps),
            att: Vector4::new(1.0, 0.0, 0.0, 0.0),
            rates_frd_radps: Vector3::zeros(),
        }
    }

    #[test]
    fn on_the_ground_still_is_landed() {
        assert!(on_ground(&at(0.0, 0.0), 0.0));
        // A ground that is not the frame's z = 0 (a platform 0.5 m up).
        assert!(on_ground(&at(-0.5 + 0.04, 0.1), -0.5));
        assert!(on_ground(&at(-0.04, -0.19), 0.0));
    }

    #[test]
    fn above_the_ground_or_moving_is_not() {
        // 6 cm up, still.
        assert!(!on_ground(&at(-0.06, 0.0), 0.0));
        // At the ground's height, still descending at a landing's speed.
        assert!(!on_ground(&at(0.0, 0.5), 0.0));
        // Bouncing up.
        assert!(!on_ground(&at(-0.01, -0.3), 0.0));
        // On another ground than the one it comes down to.
        assert!(!on_ground(&at(0.0, 0.0), -0.5));
    }

    #[test]
    fn a_second_of_low_thrust_is_ground_contact_and_a_descent_is_not() {
        let mut g = GroundContact::new();
        // A descent at hover thrust, then touching down.
        for k in 0..5_000u64 {
            assert!(!g.step(k * 1000, 0.9, 1.0));
        }
        for k in 0..1_000u64 {
            assert!(!g.step(5_000_000 + k * 1000, 0.29, 1.0), "{k}");
        }
        assert!(g.step(6_000_000, 0.0, 1.0));
        // One step of thrust starts it again.
        assert!(!g.step(6_001_000, 0.5, 1.0));
        assert!(!g.step(6_002_000, 0.1, 1.0));
        assert!(!g.step(6_003_000, f32::NAN, 1.0));
        assert!(!g.step(7_003_000, 0.1, 1.0));
    }

    #[test]
    fn nan_is_not_landed() {
        assert!(!on_ground(&at(f32::NAN, 0.0), 0.0));
        assert!(!on_ground(&at(0.0, f32::NAN), 0.0));
        assert!(!on_ground(&at(0.0, 0.0), f32::NAN));
    }
}
