//! Nonlinear equations of motion (docs/book/src/model.md §4 Euler form, §5 quaternion form),
//! with translational and rotational drag, the gyroscopic rotor term and
//! external disturbances.

use super::{lit, VehicleParams};
use crate::math as trig;
use nalgebra::{RealField, SVector, Vector3, Vector4};

/// Euler-form state `[x y z ẋ ẏ ż φ θ ψ p q r]`: NED position (m), NED velocity
/// (m/s), ZYX Euler angles (rad), body FRD rates (rad/s).
pub type EulerState<T> = SVector<T, 12>;
/// Quaternion-form state `[x y z ẋ ẏ ż q0 q1 q2 q3 p q r]`; `q` is the unit
/// body→earth quaternion, scalar first.
pub type QuatState<T> = SVector<T, 13>;
/// Input vector `U = [U1 U2 U3 U4]` (N, N, N, N·m).
pub type Input<T> = Vector4<T>;

/// Indices into [`EulerState`].
pub mod ie {
    /// North position, m.
    pub const X: usize = 0;
    /// East position, m.
    pub const Y: usize = 1;
    /// Down position, m.
    pub const Z: usize = 2;
    /// North velocity, m/s.
    pub const VX: usize = 3;
    /// East velocity, m/s.
    pub const VY: usize = 4;
    /// Down velocity, m/s.
    pub const VZ: usize = 5;
    /// Roll φ, rad.
    pub const PHI: usize = 6;
    /// Pitch θ, rad.
    pub const THETA: usize = 7;
    /// Yaw ψ, rad.
    pub const PSI: usize = 8;
    /// Roll rate p, rad/s.
    pub const P: usize = 9;
    /// Pitch rate q, rad/s.
    pub const Q: usize = 10;
    /// Yaw rate r, rad/s.
    pub const R: usize = 11;
}

/// Indices into [`QuatState`].
pub mod iq {
    /// North position, m.
    pub const X: usize = 0;
    /// East position, m.
    pub const Y: usize = 1;
    /// Down position, m.
    pub const Z: usize = 2;
    /// North velocity, m/s.
    pub const VX: usize = 3;
    /// East velocity, m/s.
    pub const VY: usize = 4;
    /// Down velocity, m/s.
    pub const VZ: usize = 5;
    /// Quaternion scalar part q0.
    pub const Q0: usize = 6;
    /// Quaternion q1 (x).
    pub const Q1: usize = 7;
    /// Quaternion q2 (y).
    pub const Q2: usize = 8;
    /// Quaternion q3 (z).
    pub const Q3: usize = 9;
    /// Roll rate p, rad/s.
    pub const P: usize = 10;
    /// Pitch rate q, rad/s.
    pub const Q: usize = 11;
    /// Yaw rate r, rad/s.
    pub const R: usize = 12;
}

/// External disturbance: force in the earth NED frame (N) and moment in the
/// body FRD frame (N·m). Zero unless a scenario adds it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Disturbance<T: RealField + Copy> {
    /// Force on the vehicle, NED, N.
    pub force_ned_n: Vector3<T>,
    /// Moment on the vehicle, body FRD, N·m.
    pub moment_body_nm: Vector3<T>,
}

impl<T: RealField + Copy> Disturbance<T> {
    /// No disturbance.
    pub fn none() -> Self {
        Self {
            force_ned_n: Vector3::zeros(),
            moment_body_nm: Vector3::zeros(),
        }
    }
}

impl<T: RealField + Copy> Default for Disturbance<T> {
    fn default() -> Self {
        Self::none()
    }
}

/// The vehicle's equations of motion with the divisions by mass and inertia
/// done once: build it when the parameters change, call it every step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vehicle<T: RealField + Copy> {
    /// The parameters the equations use.
    pub params: VehicleParams<T>,
    inv_mass: T,
    inv_inertia: [T; 3],
    weight_n: T,
}

impl<T: RealField + Copy> Vehicle<T> {
    /// Precomputes 1/m, 1/I and m·g from `params`.
    pub fn new(params: &VehicleParams<T>) -> Self {
        let [ix, iy, iz] = params.inertia_kgm2;
        Self {
            params: *params,
            inv_mass: T::one() / params.mass_kg,
            inv_inertia: [T::one() / ix, T::one() / iy, T::one() / iz],
            weight_n: params.hover_thrust_n(),
        }
    }

    /// Translational acceleration (NED, m/s²) from velocity, the body z axis in
    /// NED `(R13, R23, R33)`, thrust `U1` and the disturbance force.
    #[inline(always)]
    pub fn accel(&self, vel: &Vector3<T>, r_col3: &Vector3<T>, u1: T, d: &Disturbance<T>) -> Vector3<T> {
        let p = &self.params;
        Vector3::new(
            -(p.kt_nspm[0] * vel[0] + u1 * r_col3[0] - d.force_ned_n[0]) * self.inv_mass,
            -(p.kt_nspm[1] * vel[1] + u1 * r_col3[1] - d.force_ned_n[1]) * self.inv_mass,
            -(p.kt_nspm[2] * vel[2] - self.weight_n + u1 * r_col3[2] - d.force_ned_n[2]) * self.inv_mass,
        )
    }

    /// Body angular acceleration (rad/s²) from rates `ω = (p, q, r)`, inputs,
    /// relative rotor speed `ωr` (rad/s) and the disturbance moment (docs/book/src/model.md §4).
    #[inline(always)]
    pub fn rate_derivative(&self, w: &Vector3<T>, u: &Input<T>, omega_r: T, d: &Disturbance<T>) -> Vector3<T> {
        let p = &self.params;
        let [ix, iy, iz] = p.inertia_kgm2;
        let [krx, kry, krz] = p.kr_nms;
        let (pr, qr, rr) = (w[0], w[1], w[2]);
        let jr = p.rotor_inertia_kgm2;
        Vector3::new(
            (p.arm_m * u[1] - krx * pr + (iy - iz) * qr * rr - jr * qr * omega_r + d.moment_body_nm[0])
                * self.inv_inertia[0],
            (p.arm_m * u[2] - kry * qr + (iz - ix) * pr * rr + jr * pr * omega_r + d.moment_body_nm[1])
                * self.inv_inertia[1],
            (u[3] - krz * rr + (ix - iy) * pr * qr + d.moment_body_nm[2]) * self.inv_inertia[2],
        )
    }

    /// Time derivative of the Euler-form state (docs/book/src/model.md §4). Singular at |θ| = 90°
    /// (the result is then non-finite); use the quaternion form for aerobatics.
    pub fn euler_derivative(&self, x: &EulerState<T>, u: &Input<T>, omega_r: T, d: &Disturbance<T>) -> EulerState<T> {
        let (phi, theta, psi) = (x[6], x[7], x[8]);
        let (sphi, cphi) = trig::sin_cos(phi);
        let (sth, cth) = trig::sin_cos(theta);
        let (spsi, cpsi) = trig::sin_cos(psi);
        let inv_cth = T::one() / cth;
        let tth = sth * inv_cth;
        let vel = Vector3::new(x[3], x[4], x[5]);
        let w = Vector3::new(x[9], x[10], x[11]);
        // Third column of R_ZYX: direction of body +z (down) in NED.
        let col3 = Vector3::new(
            sphi * spsi + cphi * cpsi * sth,
            cphi * spsi * sth - sphi * cpsi,
            cphi * cth,
        );
        let a = self.accel(&vel, &col3, u[0], d);
        let wd = self.rate_derivative(&w, u, omega_r, d);
        let (pr, qr, rr) = (w[0], w[1], w[2]);
        let mut dx = EulerState::zeros();
        dx.fixed_rows_mut::<3>(0).copy_from(&vel);
        dx.fixed_rows_mut::<3>(3).copy_from(&a);
        dx[6] = pr + qr * sphi * tth + rr * cphi * tth;
        dx[7] = qr * cphi - rr * sphi;
        dx[8] = (qr * sphi + rr * cphi) * inv_cth;
        dx.fixed_rows_mut::<3>(9).copy_from(&wd);
        dx
    }

    /// Time derivative of the quaternion-form state (docs/book/src/model.md §5). The quaternion
    /// is used as given (callers renormalise after each integration step).
    pub fn quat_derivative(&self, x: &QuatState<T>, u: &Input<T>, omega_r: T, d: &Disturbance<T>) -> QuatState<T> {
        let two = lit::<T>(2.0);
        let half = lit::<T>(0.5);
        let (q0, q1, q2, q3) = (x[6], x[7], x[8], x[9]);
        let vel = Vector3::new(x[3], x[4], x[5]);
        let w = Vector3::new(x[10], x[11], x[12]);
        let col3 = Vector3::new(
            two * (q0 * q2 + q1 * q3),
            two * (q2 * q3 - q0 * q1),
            T::one() - two * (q1 * q1 + q2 * q2),
        );
        let a = self.accel(&vel, &col3, u[0], d);
        let wd = self.rate_derivative(&w, u, omega_r, d);
        let (pr, qr, rr) = (w[0], w[1], w[2]);
        // Built from one array so the vector is assembled in registers.
        QuatState::from([
            vel[0],
            vel[1],
            vel[2],
            a[0],
            a[1],
            a[2],
            -half * (pr * q1 + qr * q2 + rr * q3),
            half * (pr * q0 + rr * q2 - qr * q3),
            half * (qr * q0 - rr * q1 + pr * q3),
            half * (rr * q0 + qr * q1 - pr * q2),
            wd[0],
            wd[1],
            wd[2],
        ])
    }
}

/// [`Vehicle::rate_derivative`] for one-off calls (divides by the inertias each time).
pub fn rate_derivative<T: RealField + Copy>(
    p: &VehicleParams<T>,
    w: &Vector3<T>,
    u: &Input<T>,
    omega_r: T,
    d: &Disturbance<T>,
) -> Vector3<T> {
    Vehicle::new(p).rate_derivative(w, u, omega_r, d)
}

/// [`Vehicle::euler_derivative`] for one-off calls.
pub fn euler_derivative<T: RealField + Copy>(
    p: &VehicleParams<T>,
    x: &EulerState<T>,
    u: &Input<T>,
    omega_r: T,
    d: &Disturbance<T>,
) -> EulerState<T> {
    Vehicle::new(p).euler_derivative(x, u, omega_r, d)
}

/// [`Vehicle::quat_derivative`] for one-off calls.
pub fn quat_derivative<T: RealField + Copy>(
    p: &VehicleParams<T>,
    x: &QuatState<T>,
    u: &Input<T>,
    omega_r: T,
    d: &Disturbance<T>,
) -> QuatState<T> {
    Vehicle::new(p).quat_derivative(x, u, omega_r, d)
}
