//! Fixed-size linear algebra the controllers need beyond nalgebra's own:
//! LU solves for const-generic sizes, the algebraic Riccati equations
//! (continuous and discrete) and matrix–vector products fast on the M4.

pub mod eigen;
pub mod lu;
pub mod matvec;
pub mod riccati;

pub use eigen::*;
pub use lu::*;
pub use riccati::*;

use nalgebra::{Const, Matrix, RealField, SMatrix, Storage};

/// `out = a · b`, out of line: the design code's matrix products share one
/// copy per size instead of an unrolled copy at each call site (flash), and
/// write into a named buffer instead of a temporary (stack).
#[inline(never)]
pub fn mul_into<T, const R: usize, const K: usize, const C: usize, SA, SB>(
    a: &Matrix<T, Const<R>, Const<K>, SA>,
    b: &Matrix<T, Const<K>, Const<C>, SB>,
    out: &mut SMatrix<T, R, C>,
) where
    T: RealField + Copy,
    SA: Storage<T, Const<R>, Const<K>>,
    SB: Storage<T, Const<K>, Const<C>>,
{
    a.mul_to(b, out);
}
