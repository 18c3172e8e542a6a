//! Attitude conversions between ZYX Euler angles and unit quaternions
//! (scalar first, body FRD → earth NED), and between the two state forms.

use super::{lit, EulerState, QuatState};
use crate::math as trig;
use nalgebra::{RealField, Vector3, Vector4};

/// A quaternion `[q0 q1 q2 q3]`, scalar first.
pub type Quat<T> = Vector4<T>;

/// Quaternion of the ZYX rotation with roll φ, pitch θ, yaw ψ (rad).
pub fn euler_to_quat<T: RealField + Copy>(phi: T, theta: T, psi: T) -> Quat<T> {
    let h = lit::<T>(0.5);
    quat_of_half_angles(trig::sin_cos(phi * h), trig::sin_cos(theta * h), trig::sin_cos(psi * h))
}

/// [`euler_to_quat`] from the `(sin, cos)` of the half-angles `φ/2`, `θ/2`,
/// `ψ/2`, for a caller that has them without the angles' sines (see
/// [`crate::math::half_angle`]).
pub fn quat_of_half_angles<T: RealField + Copy>((sr, cr): (T, T), (sp, cp): (T, T), (sy, cy): (T, T)) -> Quat<T> {
    Vector4::new(
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )
}

/// ZYX Euler angles `(φ, θ, ψ)` (rad) of a unit quaternion. θ is clamped to
/// ±90° where rounding pushes `sin θ` past ±1.
pub fn quat_to_euler<T: RealField + Copy>(q: &Quat<T>) -> Vector3<T> {
    let two = lit::<T>(2.0);
    let (q0, q1, q2, q3) = (q[0], q[1], q[2], q[3]);
    let phi = (two * (q0 * q1 + q2 * q3)).atan2(T::one() - two * (q1 * q1 + q2 * q2));
    let s = (two * (q0 * q2 - q3 * q1)).max(-T::one()).min(T::one());
    let theta = s.asin();
    let psi = (two * (q0 * q3 + q1 * q2)).atan2(T::one() - two * (q2 * q2 + q3 * q3));
    Vector3::new(phi, theta, psi)
}

/// Hamilton product `a ⊗ b`.
pub fn quat_mul<T: RealField + Copy>(a: &Quat<T>, b: &Quat<T>) -> Quat<T> {
    Vector4::new(
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    )
}

/// Conjugate (the inverse of a unit quaternion).
pub fn quat_conj<T: RealField + Copy>(q: &Quat<T>) -> Quat<T> {
    Vector4::new(q[0], -q[1], -q[2], -q[3])
}

/// Normalises `q`; a zero or non-finite quaternion becomes the identity.
pub fn quat_normalize<T: RealField + Copy>(q: &Quat<T>) -> Quat<T> {
    let n = trig::sqrt(q.norm_squared());
    if n.is_finite() && n > T::default_epsilon() {
        q * (T::one() / n)
    } else {
        Vector4::new(T::one(), T::zero(), T::zero(), T::zero())
    }
}

/// Rotation matrix (body → earth) of a unit quaternion.
pub fn quat_to_rotation<T: RealField + Copy>(q: &Quat<T>) -> nalgebra::Matrix3<T> {
    let two = lit::<T>(2.0);
    let (a, b, c, d) = (q[0], q[1], q[2], q[3]);
    nalgebra::Matrix3::new(
        T::one() - two * (c * c + d * d),
        two * (b * c - a * d),
        two * (b * d + a * c),
        two * (b * c + a * d),
        T::one() - two * (b * b + d * d),
        two * (c * d - a * b),
        two * (b * d - a * c),
        two * (c * d + a * b),
        T::one() - two * (b * b + c * c),
    )
}

/// Quaternion-form state with the same pose, velocity and rates as an Euler state.
pub fn euler_state_to_quat<T: RealField + Copy>(x: &EulerState<T>) -> QuatState<T> {
    let q = euler_to_quat(x[6], x[7], x[8]);
    let mut out = QuatState::zeros();
    out.fixed_rows_mut::<6>(0).copy_from(&x.fixed_rows::<6>(0));
    out.fixed_rows_mut::<4>(6).copy_from(&q);
    out.fixed_rows_mut::<3>(10).copy_from(&x.fixed_rows::<3>(9));
    out
}

/// Euler-form state with the same pose, velocity and rates as a quaternion state.
pub fn quat_state_to_euler<T: RealField + Copy>(x: &QuatState<T>) -> EulerState<T> {
    let q: Quat<T> = x.fixed_rows::<4>(6).into_owned();
    let e = quat_to_euler(&q);
    let mut out = EulerState::zeros();
    out.fixed_rows_mut::<6>(0).copy_from(&x.fixed_rows::<6>(0));
    out.fixed_rows_mut::<3>(6).copy_from(&e);
    out.fixed_rows_mut::<3>(9).copy_from(&x.fixed_rows::<3>(10));
    out
}
