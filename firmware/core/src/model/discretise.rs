//! Exact zero-order-hold discretisation: `Ad = e^{A·Ts}`, `Bd = ∫₀^Ts e^{Aτ}dτ · B`.
//!
//! Scaling and squaring on the pair (Φ, Γ) = (e^{Ah}, ∫₀^h e^{Aτ}dτ): a Taylor
//! series at `h = Ts/2^s` with `‖A·h‖ ≤ 1/2`, then `s` doublings
//! `Φ(2h) = Φ(h)²`, `Γ(2h) = (I + Φ(h))·Γ(h)`. Fixed-size, bounded loops, no
//! allocation; the only failure is non-finite or absurdly large input.

use super::lit;
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
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn zoh<T: RealField + Copy, const N: usize, const M: usize>(
    a: &SMatrix<T, N, N>,
    b: &SMatrix<T, N, M>,
    ts: T,
) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, M>), DiscretiseError> {
    let (phi, gamma) = expm_with_integral(a, ts)?;
    let bd = gamma * b;
    if bd.iter().all(|v| v.is_finite()) {
        Ok((phi, bd))
    } else {
        Err(DiscretiseError::NonFinite)
    }
}

/// `(e^{A·t}, ∫₀^t e^{Aτ}dτ)` for a square A and time `t` (s).
// Design-time code: kept out of line so that its large frames are not
// merged into the callers' (stack) and not copied into each (flash).
#[inline(never)]
pub fn expm_with_integral<T: RealField + Copy, const N: usize>(
    a: &SMatrix<T, N, N>,
    t: T,
) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, N>), DiscretiseError> {
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
    let ah = a * h;
    let id = SMatrix::<T, N, N>::identity();
    let mut term = id; // (Ah)^k / k!
    let mut phi = id;
    let mut gsum = id; // Σ (Ah)^k/(k+1)!
    for k in 1..=TAYLOR_TERMS {
        let kk: T = lit(k as f64);
        term = (term * ah) / kk;
        phi += term;
        gsum += term / (kk + T::one());
    }
    let mut gamma = gsum * h;
    for _ in 0..s {
        gamma = (id + phi) * gamma;
        phi = phi * phi;
    }
    if phi.iter().chain(gamma.iter()).all(|v| v.is_finite()) {
        Ok((phi, gamma))
    } else {
        Err(DiscretiseError::NonFinite)
    }
}
