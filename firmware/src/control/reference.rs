//! From a desired acceleration to the attitude and thrust that produce it
//! (thesis 3.79, 3.85, 3.86 — an exact inversion of the translational
//! dynamics of SPEC §4), and the reference feed-forward modes.

use crate::lit;
use crate::model::VehicleParams;
use nalgebra::{RealField, Vector3};

/// How much of the reference the controllers feed forward.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReferenceMode {
    /// As the thesis: the reference position and velocity enter the feedback
    /// (3.78, 3.83, 3.84); no acceleration, attitude or thrust feed-forward.
    Thesis,
    /// Adds the reference acceleration: the attitude and thrust it implies are
    /// fed forward, so moving references are tracked without feedback lag.
    Feedforward,
}

/// Desired roll, pitch and thrust for a desired acceleration and heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiltThrust<T: RealField + Copy> {
    /// Desired roll φd, rad.
    pub roll_rad: T,
    /// Desired pitch θd, rad.
    pub pitch_rad: T,
    /// Thrust that gives the desired vertical acceleration at this tilt, N.
    pub thrust_n: T,
}

/// Largest commanded tilt, rad (45°): keeps the thrust axis well away from
/// horizontal, where altitude cannot be held.
pub const MAX_TILT_RAD: f64 = core::f64::consts::FRAC_PI_4;

/// Attitude and thrust for acceleration `acc_d` (NED, m/s²) at velocity `vel`
/// (for drag compensation) and heading `yaw` (thesis 3.85, 3.86, 3.79 with the
/// desired angles). With `A = acc_d + kt∘vel/m`:
/// `θd = atan((−cψ·Ax − sψ·Ay)/(g − Az))`,
/// `φd = atan((−sψ·Ax + cψ·Ay)·cos θd/(g − Az))`,
/// `U1 = m(g − Az)/(cos φd cos θd)`.
/// `g − Az` is kept ≥ 0.2 g (no commanded free fall) and the tilt ≤ 45°.
pub fn tilt_and_thrust<T: RealField + Copy>(
    p: &VehicleParams<T>,
    acc_d: &Vector3<T>,
    vel: &Vector3<T>,
    yaw: T,
) -> TiltThrust<T> {
    let m = p.mass_kg;
    let g = p.gravity_mps2;
    let ax = acc_d[0] + p.kt_nspm[0] / m * vel[0];
    let ay = acc_d[1] + p.kt_nspm[1] / m * vel[1];
    let az = acc_d[2] + p.kt_nspm[2] / m * vel[2];
    let lift = (g - az).max(lit::<T>(0.2) * g);
    let (s, c) = yaw.sin_cos();
    let max_tilt = lit::<T>(MAX_TILT_RAD);
    let pitch = ((-c * ax - s * ay) / lift)
        .atan()
        .max(-max_tilt)
        .min(max_tilt);
    let roll = ((-s * ax + c * ay) * pitch.cos() / lift)
        .atan()
        .max(-max_tilt)
        .min(max_tilt);
    TiltThrust {
        roll_rad: roll,
        pitch_rad: pitch,
        thrust_n: m * lift / (roll.cos() * pitch.cos()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{euler_derivative, hover_euler_state, Disturbance, VehicleParams};
    use nalgebra::Vector4;

    #[test]
    fn tilt_and_thrust_produce_the_desired_acceleration() {
        // Independent truth: put the vehicle at the returned attitude with the
        // returned thrust and evaluate the nonlinear dynamics.
        let p = VehicleParams::<f64>::os4();
        for (acc, vel, yaw) in [
            (
                Vector3::new(1.0, -0.5, -0.8),
                Vector3::new(0.3, 0.2, -0.1),
                0.3,
            ),
            (
                Vector3::new(-2.0, 1.5, 0.5),
                Vector3::new(-1.0, 0.0, 0.4),
                -2.4,
            ),
            (Vector3::zeros(), Vector3::zeros(), 1.0),
        ] {
            let tt = tilt_and_thrust(&p, &acc, &vel, yaw);
            let mut x = hover_euler_state(&Vector3::zeros(), yaw);
            x[3] = vel[0];
            x[4] = vel[1];
            x[5] = vel[2];
            x[6] = tt.roll_rad;
            x[7] = tt.pitch_rad;
            let u = Vector4::new(tt.thrust_n, 0.0, 0.0, 0.0);
            let d = euler_derivative(&p, &x, &u, 0.0, &Disturbance::none());
            let got = Vector3::new(d[3], d[4], d[5]);
            assert!((got - acc).norm() < 1e-12, "{got} vs {acc}");
        }
    }

    #[test]
    fn limits_hold_for_extreme_requests() {
        let p = VehicleParams::<f64>::os4();
        let tt = tilt_and_thrust(
            &p,
            &Vector3::new(100.0, -100.0, 50.0),
            &Vector3::zeros(),
            0.0,
        );
        assert!(
            tt.roll_rad.abs() <= MAX_TILT_RAD + 1e-12 && tt.pitch_rad.abs() <= MAX_TILT_RAD + 1e-12
        );
        assert!(tt.thrust_n > 0.0 && tt.thrust_n.is_finite());
    }
}
