//! The vehicle model (SPEC §2–7), generic over the float type `T: RealField + Copy`.
//!
//! Split by concern, nalgebra style: [`params`] (construction), [`mixer`]
//! (rotor speeds ↔ inputs), [`dynamics`] (nonlinear ODEs), [`attitude`]
//! (Euler/quaternion conversion), [`trim`] (hover), [`linear`] (Jacobians),
//! [`discretise`] (matrix exponential, ZOH).

pub mod attitude;
pub mod discretise;
pub mod dynamics;
pub mod linear;
pub mod mixer;
pub mod params;
pub mod trim;

pub use attitude::*;
pub use discretise::*;
pub use dynamics::*;
pub use linear::*;
pub use mixer::*;
pub use params::*;
pub use trim::*;

use nalgebra::RealField;

/// Converts an `f64` literal into the model's float type (exact for `f64`,
/// rounded for `f32`). Never fails and never panics.
#[inline(always)]
pub fn lit<T: RealField + Copy>(x: f64) -> T {
    nalgebra::convert(x)
}

#[cfg(test)]
mod tests;
