//! Exact zero-order-hold discretisation: `Ad = e^{A·Ts}`, `Bd = ∫₀^Ts e^{Aτ}dτ · B`.
//!
//! Scaling and squaring on the pair (Φ, Γ) = (e^{Ah}, ∫₀^h e^{Aτ}dτ): a Taylor
//! series at `h = Ts/2^s` with `‖A·h‖ ≤ 1/2`, then `s` doublings
//! `Φ(2h) = Φ(h)²`, `Γ(2h) = (I + Φ(h))·Γ(h)`. Fixed-size, bounded loops, no
//! allocation; the only failure is non-finite or absurdly large input.

use super::lit;
use crate::linalg::mul_into;
use nalgebra::{RealField, SMatrix};

/// Why a discretisation failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DiscretiseError {
    /// A, B or Ts contained NaN/∞, or Ts ≤ 0.
    NonFinite,
    /// ‖A·Ts‖ needs more than [`MAX_SQUARINGS`] doublings.
    TooStiff,
}

impl core::fmt::Display for DiscretiseError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            DiscretiseError::NonFinite => "A, B or the sample time has NaN/inf, or the sample time is not positive",
            DiscretiseError::TooStiff => "the model is too stiff for the sample time (more than 40 squarings)",
        })
    }
}

impl core::error::Error for DiscretiseError {}

/// Upper bound on scaling-and-squaring doublings (‖A·Ts‖ up to 2^39).
pub const MAX_SQUARINGS: u32 = 40;
/// Taylor terms used at the scaled step; with ‖A·h‖ ≤ 1/2 the truncation
/// error is below 1e-17 relative.
pub const TAYLOR_TERMS: u32 = 14;

/// Discrete pair `(Ad, Bd)` of `ẋ = A x + B u` under zero-order hold at `ts` (s).
///
/// ```
/// use fc_core::model::zoh;
/// use nalgebra::{Matrix2, Vector2};
///
/// // A double integrator (position, velocity; input acceleration) held for
/// // T = 0.1 s: Ad = [[1, T], [0, 1]], Bd = [T²/2, T], exactly.
/// let a = Matrix2::new(0.0, 1.0, 0.0, 0.0);
/// let (ad, bd) = zoh(&a, &Vector2::new(0.0, 1.0), 0.1)?;
/// assert!((ad - Matrix2::new(1.0, 0.1, 0.0, 1.0)).amax() < 1e-15);
/// assert!((bd - Vector2::new(0.005, 0.1)).amax() < 1e-15);
/// # Ok::<(), fc_core::model::DiscretiseError>(())
/// ```
pub fn zoh<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    ts: T,
) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, M>), DiscretiseError> {
    let mut ad = SMatrix::zeros();
    let mut bd = SMatrix::zeros();
    zoh_into(a, b, ts, &mut ad, &mut bd)?;
    Ok((ad, bd))
}

/// [`zoh`] into the caller's matrices: what the design code on the MCU
/// calls, so that no result is copied through the stack.
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn zoh_into<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    ts: T,
    ad: &mut SMatrix<T, N, N>,
    bd: &mut SMatrix<T, N, M>,
) -> Result<(), DiscretiseError> {
    let mut gamma = SMatrix::<T, N, N>::zeros();
    expm_with_integral_into(a, ts, ad, &mut gamma)?;
    mul_into(&gamma, b, bd);
    if bd.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(DiscretiseError::NonFinite)
    }
}

/// `(e^{A·t}, ∫₀^t e^{Aτ}dτ)` for a square A and time `t` (s).
pub fn expm_with_integral<T: RealField + Copy, const N: usize>(
    a: &SMatrix<T, N, N>,
    t: T,
) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, N>), DiscretiseError> {
    let mut phi = SMatrix::zeros();
    let mut gamma = SMatrix::zeros();
    expm_with_integral_into(a, t, &mut phi, &mut gamma)?;
    Ok((phi, gamma))
}

/// [`expm_with_integral`] into the caller's `phi` and `gamma`; the series
/// runs in four named N×N buffers written in place (no matrix temporaries).
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn expm_with_integral_into<T: RealField + Copy, const N: usize>(
    a: &SMatrix<T, N, N>,
    t: T,
    phi: &mut SMatrix<T, N, N>,
    gamma: &mut SMatrix<T, N, N>,
) -> Result<(), DiscretiseError> {
    if !(t.is_finite() && t > T::zero() && a.iter().all(|v| v.is_finite())) {
        return Err(DiscretiseError::NonFinite);
    }
    // Infinity norm (max row sum) of A·t.
    let mut norm = T::zero();
    for i in 0..N {
        let mut row = T::zero();
        for j in 0..N {
            row += a[(i, j)].abs();
        }
        norm = norm.max(row * t);
    }
    let mut s = 0u32;
    let mut h = t;
    let half = lit::<T>(0.5);
    while norm > half {
        if s >= MAX_SQUARINGS {
            return Err(DiscretiseError::TooStiff);
        }
        norm *= half;
        h *= half;
        s += 1;
    }
    // Φ = Σ (Ah)^k/k!,  Γ = h Σ (Ah)^k/(k+1)!
    let mut ah = *a;
    ah.scale_mut(h);
    let mut term = SMatrix::<T, N, N>::identity(); // (Ah)^k / k!
    phi.fill_with_identity();
    gamma.fill_with_identity(); // Σ (Ah)^k/(k+1)!, then Γ
    let mut tmp = SMatrix::<T, N, N>::zeros();
    for k in 1..=TAYLOR_TERMS {
        let kk: T = lit(k as f64);
        mul_into(&term, &ah, &mut tmp);
        let k1 = kk + T::one();
        for ((t, x), (p, g)) in term
            .iter_mut()
            .zip(tmp.iter())
            .zip(phi.iter_mut().zip(gamma.iter_mut()))
        {
            *t = *x / kk;
            *p += *t;
            *g += *t / k1;
        }
    }
    gamma.scale_mut(h);
    // `ah` and `term` are free now: they hold I + Φ and the products.
    for _ in 0..s {
        // Γ ← (I + Φ)Γ, Φ ← Φ² (I + Φ entry by entry, as the sum of matrices).
        for i in 0..N {
            for j in 0..N {
                ah[(i, j)] = if i == j { T::one() } else { T::zero() } + phi[(i, j)];
            }
        }
        mul_into(&ah, &*gamma, &mut term);
        gamma.copy_from(&term);
        mul_into(&*phi, &*phi, &mut term);
        phi.copy_from(&term);
    }
    if phi.iter().chain(gamma.iter()).all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(DiscretiseError::NonFinite)
    }
}
