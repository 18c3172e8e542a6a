//! The vehicle model (docs/book/src/model.md §2–7), generic over the float type `T: RealField + Copy`.
//!
//! Split by concern, nalgebra style: [`params`] (construction), [`mixer`]
//! (rotor speeds ↔ inputs), [`dynamics`] (nonlinear ODEs), [`attitude`]
//! (Euler/quaternion conversion), [`trim`] (hover), [`linear`] (Jacobians),
//! [`discretise`] (matrix exponential, ZOH), [`airframe`] (motor commands for
//! any four-rotor layout).

pub mod airframe;
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

/// Which attitude coordinates a model or controller is written in.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "lowercase")
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AttitudeForm {
    /// ZYX Euler angles (12 states); singular at |θ| = 90°. In the MPC: roll,
    /// pitch and heading-relative yaw (rad).
    Euler,
    /// Unit quaternion (13 states); no singularity. In the MPC: the vector
    /// part of the heading-relative quaternion (≈ half-angles).
    Quaternion,
}

impl AttitudeForm {
    /// Both forms, Euler first (table order).
    pub const ALL: [AttitudeForm; 2] = [AttitudeForm::Euler, AttitudeForm::Quaternion];

    /// Lower-case name (`euler`, `quaternion`): command line, JSON, file names.
    pub const fn name(self) -> &'static str {
        match self {
            AttitudeForm::Euler => "euler",
            AttitudeForm::Quaternion => "quaternion",
        }
    }

    /// Title in tables (`Euler`, `quaternion`).
    pub const fn title(self) -> &'static str {
        match self {
            AttitudeForm::Euler => "Euler",
            AttitudeForm::Quaternion => "quaternion",
        }
    }
}

/// Converts an `f64` literal into the model's float type (exact for `f64`,
/// rounded for `f32`). Never fails and never panics.
#[inline(always)]
pub fn lit<T: RealField + Copy>(x: f64) -> T {
    nalgebra::convert(x)
}

#[cfg(test)]
mod tests;
