//! Sine and cosine for the control loop, fast on the Cortex-M4F.
//!
//! `libm`'s `sinf`/`cosf` (what nalgebra's `f32::sin` calls in `no_std`)
//! evaluate in `f64`, which the M4's single-precision FPU does not have: every
//! call becomes hundreds of soft-float instructions, and the MPC's reference
//! over its horizon makes hundreds of calls per step. Here `f32` gets an
//! all-`f32` evaluation (Cody–Waite reduction by π/2 in three parts, then
//! the minimax polynomials of musl's `__sindf`/`__cosdf` on [−π/4, π/4]);
//! every other float type (the host plant's `f64`) keeps `libm`'s.
//!
//! Accuracy of the `f32` path: |error| ≤ 2·10⁻⁷ for |x| ≤ 10⁴ rad (tested
//! against `f64`); outside that range and for non-finite input it falls back
//! to `libm`.

use crate::lit;
use core::any::Any;
use nalgebra::RealField;

/// `(sin x, cos x)`, x in rad.
#[inline]
pub fn sin_cos<T: RealField + Copy>(x: T) -> (T, T) {
    if let Some(&v) = (&x as &dyn Any).downcast_ref::<f32>() {
        let (s, c) = sin_cos_f32(v);
        let (mut so, mut co) = (T::zero(), T::zero());
        if let (Some(a), Some(b)) = (
            (&mut so as &mut dyn Any).downcast_mut::<f32>(),
            (&mut co as &mut dyn Any).downcast_mut::<f32>(),
        ) {
            *a = s;
            *b = c;
            return (so, co);
        }
    }
    x.sin_cos()
}

/// `√x`: for `f32` the FPU's `VSQRT.F32` on the chip ([`fc_fpu::sqrt`]:
/// an instruction where libm's is an algorithm in software, the same
/// correctly rounded bits), `T::sqrt` for any other `T`.
#[inline]
pub fn sqrt<T: RealField + Copy>(x: T) -> T {
    if let Some(&v) = (&x as &dyn Any).downcast_ref::<f32>() {
        let mut out = T::zero();
        if let Some(o) = (&mut out as &mut dyn Any).downcast_mut::<f32>() {
            *o = fc_fpu::sqrt(v);
            return out;
        }
    }
    x.sqrt()
}

/// `(sin a/2, cos a/2)` from `(sin a, cos a)` for `|a| < π`:
/// `cos a/2 = √((1 + cos a)/2)` (≥ 0 there), `sin a/2 = sin a / (2 cos a/2)`
/// (accurate to a few ulps for `|a| ≤ π/2`; it loses digits towards ±π,
/// where `1 + cos a` cancels).
/// A square root and a division in place of a sine and a cosine (the
/// MPC's reference attitude: its roll and pitch are within ±45°).
#[inline]
pub fn half_angle<T: RealField + Copy>(s: T, c: T) -> (T, T) {
    let ch = sqrt((T::one() + c) * lit::<T>(0.5));
    (s / (ch + ch), ch)
}

/// `sin x`, x in rad.
#[inline]
pub fn sin<T: RealField + Copy>(x: T) -> T {
    sin_cos(x).0
}

/// `cos x`, x in rad.
#[inline]
pub fn cos<T: RealField + Copy>(x: T) -> T {
    sin_cos(x).1
}

/// `v` limited to `[lo, hi]` by comparisons. On targets without a
/// floating-point min/max instruction (ARMv7E-M), `f32::max`/`min` are calls
/// into `fmaxf`/`fminf` for their NaN rules; inner loops on finite data use
/// this instead. A NaN `v` comes back unchanged.
#[inline(always)]
pub fn clamp<T: RealField + Copy>(v: T, lo: T, hi: T) -> T {
    if v < lo {
        lo
    } else if v > hi {
        hi
    } else {
        v
    }
}

/// `v` limited to `[−lim, lim]` by comparisons (see [`clamp`]), for a
/// symmetric limit where NaN must not pass: NaN gives `−lim`, as
/// `v.max(−lim).min(lim)` does.
#[inline(always)]
pub fn limit<T: RealField + Copy>(v: T, lim: T) -> T {
    if v > lim {
        lim
    } else if v >= -lim {
        v
    } else {
        -lim
    }
}

/// The larger of `a` and `b` by comparison (see [`clamp`]); `a` if either is NaN.
#[inline(always)]
pub fn max<T: RealField + Copy>(a: T, b: T) -> T {
    if b > a {
        b
    } else {
        a
    }
}

/// π/2 in three parts whose products with a small integer are exact in f32.
const PIO2_1: f32 = f32::from_bits(0x3FC9_0000); // 1.5703125
const PIO2_2: f32 = f32::from_bits(0x39FD_A000); // 4.837512969970703125e-4
const PIO2_3: f32 = f32::from_bits(0x33A2_2168); // 7.54978995489188216e-8
const FRAC_2_PI: f32 = core::f32::consts::FRAC_2_PI;

/// sin on [−π/4, π/4] (musl `__sindf` coefficients).
#[inline]
fn sin_kernel(r: f32) -> f32 {
    const S1: f32 = -0.166_666_67;
    const S2: f32 = 0.008_333_329;
    const S3: f32 = -1.983_933_5e-4;
    const S4: f32 = 2.718_311_5e-6;
    let z = r * r;
    r + r * z * (S1 + z * (S2 + z * (S3 + z * S4)))
}

/// cos on [−π/4, π/4] (musl `__cosdf` coefficients).
#[inline]
fn cos_kernel(r: f32) -> f32 {
    const C0: f32 = -0.5;
    const C1: f32 = 0.041_666_623;
    const C2: f32 = -0.001_388_676_4;
    const C3: f32 = 2.439_044_9e-5;
    let z = r * r;
    1.0 + z * (C0 + z * (C1 + z * (C2 + z * C3)))
}

/// `(sin x, cos x)` evaluated in `f32` only.
pub fn sin_cos_f32(x: f32) -> (f32, f32) {
    if !x.is_finite() || x.abs() > 1.0e4 {
        return (libm::sinf(x), libm::cosf(x));
    }
    // Nearest multiple of π/2 (|k| ≤ 6367, exact in f32 and i32).
    let kf = x * FRAC_2_PI;
    let k = if kf >= 0.0 {
        (kf + 0.5) as i32
    } else {
        (kf - 0.5) as i32
    };
    let kf = k as f32;
    let r = ((x - kf * PIO2_1) - kf * PIO2_2) - kf * PIO2_3;
    let (s, c) = (sin_kernel(r), cos_kernel(r));
    match k & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f32_path_matches_f64_to_2e7() {
        let mut worst = 0.0f64;
        let n = 400_000;
        for i in 0..=n {
            // Dense near 0 and over many turns, both signs.
            let x = -10_000.0f32 + 20_000.0 * (i as f32 / n as f32);
            for x in [x, x * 1e-3, x * 1e-4] {
                let (s, c) = sin_cos_f32(x);
                let xd = x as f64;
                worst = worst.max((s as f64 - xd.sin()).abs()).max((c as f64 - xd.cos()).abs());
            }
        }
        assert!(worst <= 2e-7, "worst error {worst:e}");
    }

    #[test]
    fn quadrant_boundaries_and_identities() {
        use core::f32::consts::{FRAC_PI_2, PI};
        for (x, s, c) in [
            (0.0f32, 0.0f32, 1.0f32),
            (FRAC_PI_2, 1.0, 0.0),
            (PI, 0.0, -1.0),
            (-FRAC_PI_2, -1.0, 0.0),
        ] {
            let (a, b) = sin_cos_f32(x);
            assert!((a - s).abs() < 1e-7 && (b - c).abs() < 1e-7, "{x}: {a} {b}");
        }
        // Odd/even symmetry holds exactly (the reduction is symmetric).
        for i in 0..1000 {
            let x = i as f32 * 0.0137;
            let (s1, c1) = sin_cos_f32(x);
            let (s2, c2) = sin_cos_f32(-x);
            assert_eq!(s1, -s2);
            assert_eq!(c1, c2);
        }
    }

    /// Against f64's own sine and cosine of the half-angle, for angles over
    /// (−π, π) given as the f32 sine and cosine of their whole.
    #[test]
    fn half_angles_match_the_half_angle_sine_and_cosine() {
        let n = 20_000;
        let mut worst = 0.0f64;
        for i in 1..n {
            let a = -3.1f64 + 6.2 * i as f64 / n as f64;
            let (s, c) = half_angle(a.sin() as f32, a.cos() as f32);
            worst = worst
                .max((s as f64 - (a / 2.0).sin()).abs())
                .max((c as f64 - (a / 2.0).cos()).abs());
        }
        // Within ±45° (the MPC's use) a few f32 ulps; near ±π, where
        // 1 + cos a cancels, it loses digits, as the doc says it may.
        let mut near = 0.0f64;
        for i in 0..=2_000 {
            let a = -core::f64::consts::FRAC_PI_4 + core::f64::consts::FRAC_PI_2 * i as f64 / 2_000.0;
            let (s, c) = half_angle(a.sin() as f32, a.cos() as f32);
            near = near
                .max((s as f64 - (a / 2.0).sin()).abs())
                .max((c as f64 - (a / 2.0).cos()).abs());
        }
        assert!(near <= 2e-7, "within 45°: {near:e}");
        assert!(worst <= 1e-3, "over (−3.1, 3.1): {worst:e}");
    }

    #[test]
    fn non_finite_and_huge_fall_back() {
        assert!(sin_cos_f32(f32::NAN).0.is_nan());
        assert!(sin_cos_f32(f32::INFINITY).1.is_nan());
        let (s, _) = sin_cos_f32(1.0e6);
        assert!((s as f64 - (1.0e6f64).sin()).abs() < 1e-6);
    }

    #[test]
    fn clamp_and_max_by_comparison() {
        assert_eq!(clamp(5.0f32, -1.0, 2.0), 2.0);
        assert_eq!(clamp(-5.0f32, -1.0, 2.0), -1.0);
        assert_eq!(clamp(0.5f32, -1.0, 2.0), 0.5);
        assert!(clamp(f32::NAN, -1.0, 2.0).is_nan());
        assert_eq!(max(1.0f64, 3.0), 3.0);
        assert_eq!(max(3.0f64, f64::NAN), 3.0);
    }

    #[test]
    fn generic_dispatch() {
        // f64 keeps libm's exactly; f32 takes the f32 path.
        assert_eq!(sin_cos(0.7f64), 0.7f64.sin_cos());
        assert_eq!(sin_cos(0.7f32), sin_cos_f32(0.7));
    }
}
