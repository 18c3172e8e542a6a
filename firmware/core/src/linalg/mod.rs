//! Fixed-size linear algebra the controllers need beyond nalgebra's own:
//! LU solves for const-generic sizes and the algebraic Riccati equations
//! (continuous and discrete).

pub mod eigen;
pub mod lu;
pub mod riccati;

pub use eigen::*;
pub use lu::*;
pub use riccati::*;
