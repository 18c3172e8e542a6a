//! The mixer (docs/book/src/model.md §3): rotor speeds ↔ inputs `U`, with the corrected inverse.
//!
//! Rotor 1 front (+x body), 2 right (+y), 3 rear, 4 left; rotors 1 and 3 spin
//! the opposite way to 2 and 4.

use super::{lit, VehicleParams};
use nalgebra::{RealField, Vector4};

/// Inputs `U` (N, N, N, N·m) produced by the given squared rotor speeds (rad²/s²).
pub fn mix<T: RealField + Copy>(p: &VehicleParams<T>, omega_sq: &Vector4<T>) -> Vector4<T> {
    let w = omega_sq;
    Vector4::new(
        p.kf_ns2 * (w[0] + w[1] + w[2] + w[3]),
        p.kf_ns2 * (w[3] - w[1]),
        p.kf_ns2 * (w[0] - w[2]),
        p.km_nms2 * (w[0] - w[1] + w[2] - w[3]),
    )
}

/// Squared rotor speeds (rad²/s²) that produce `u` exactly, before any clamping.
/// Entries may be negative when `u` is not reachable.
pub fn unmix<T: RealField + Copy>(p: &VehicleParams<T>, u: &Vector4<T>) -> Vector4<T> {
    let a = u[0] / (lit::<T>(4.0) * p.kf_ns2);
    let b2 = u[1] / (lit::<T>(2.0) * p.kf_ns2);
    let b3 = u[2] / (lit::<T>(2.0) * p.kf_ns2);
    let d = u[3] / (lit::<T>(4.0) * p.km_nms2);
    Vector4::new(a + b3 + d, a - b2 - d, a - b3 + d, a + b2 - d)
}

/// Rotor speeds (rad/s) commanded by `u`, clamped to `[0, Ωmax]`.
/// Negative or NaN squared speeds give 0: a corrupt command stops that rotor
/// rather than poisoning the state.
pub fn rotor_speeds<T: RealField + Copy>(p: &VehicleParams<T>, u: &Vector4<T>) -> Vector4<T> {
    unmix(p, u).map(|w2| {
        clamp_speed(
            p,
            if w2 > T::zero() {
                crate::math::sqrt(w2)
            } else {
                T::zero()
            },
        )
    })
}

/// Clamps one rotor speed to `[0, Ωmax]` (NaN → 0).
#[inline]
pub fn clamp_speed<T: RealField + Copy>(p: &VehicleParams<T>, w: T) -> T {
    if w > p.omega_max_radps {
        p.omega_max_radps
    } else if w > T::zero() {
        w
    } else {
        T::zero()
    }
}

/// Inputs realised by rotors spinning at `omega` (rad/s).
pub fn realised_inputs<T: RealField + Copy>(p: &VehicleParams<T>, omega: &Vector4<T>) -> Vector4<T> {
    mix(p, &omega.component_mul(omega))
}

/// Relative rotor speed for the gyroscopic term, `ωr = −Ω1 + Ω2 − Ω3 + Ω4`, rad/s.
#[inline]
pub fn gyro_speed<T: RealField + Copy>(omega: &Vector4<T>) -> T {
    -omega[0] + omega[1] - omega[2] + omega[3]
}
