//! Vehicle parameters (docs/book/src/model.md §2, OS4 quadrotor) and the input boxes derived from them.

use super::lit;
use nalgebra::{RealField, Vector4};

/// The plausible range of one vehicle parameter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamRange {
    /// The field (with its unit, as in [`VehicleParams`]).
    pub field: &'static str,
    /// Smallest accepted value.
    pub lo: f64,
    /// Largest accepted value.
    pub hi: f64,
}

/// What [`VehicleParams::check`] accepts, in field order: wide enough for
/// any multirotor from a 10 g micro to a 100 kg heavy lifter, narrow enough
/// that every derived quantity stays finite in f32 (a design with an
/// inertia of 1e300 or 1e-300 is refused here, by name, instead of failing
/// somewhere inside a Riccati solve).
pub const PARAM_RANGES: [ParamRange; 18] = {
    const fn r(field: &'static str, lo: f64, hi: f64) -> ParamRange {
        ParamRange { field, lo, hi }
    }
    [
        r("mass_kg", 0.01, 100.0),
        r("gravity_mps2", 0.1, 100.0),
        r("inertia_kgm2[0]", 1e-7, 100.0),
        r("inertia_kgm2[1]", 1e-7, 100.0),
        r("inertia_kgm2[2]", 1e-7, 100.0),
        r("arm_m", 0.01, 5.0),
        r("rotor_inertia_kgm2", 0.0, 0.1),
        r("kf_ns2", 1e-10, 1.0),
        r("km_nms2", 1e-12, 1.0),
        r("kt_nspm[0]", 0.0, 100.0),
        r("kt_nspm[1]", 0.0, 100.0),
        r("kt_nspm[2]", 0.0, 100.0),
        r("kr_nms[0]", 0.0, 100.0),
        r("kr_nms[1]", 0.0, 100.0),
        r("kr_nms[2]", 0.0, 100.0),
        r("omega_max_radps", 1.0, 1e5),
        r("rotor_tau_s", 1e-6, 10.0),
        r("rotor_gain", 0.01, 10.0),
    ]
};

/// A vehicle parameter out of its plausible range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ParamError {
    /// Which parameter and what it may be.
    pub range: ParamRange,
    /// The value given (NaN if not representable).
    pub value: f64,
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "vehicle parameter {} = {:?} is out of range: must be in [{:?}, {:?}]",
            self.range.field, self.value, self.range.lo, self.range.hi
        )
    }
}

impl core::error::Error for ParamError {}

/// Physical parameters of the quadrotor. Units are in the field names.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct VehicleParams<T> {
    /// Mass m, kg.
    pub mass_kg: T,
    /// Gravity g, m/s² (positive; acts along +z in NED).
    pub gravity_mps2: T,
    /// Principal inertias (Ix, Iy, Iz) about body FRD axes, kg·m².
    pub inertia_kgm2: [T; 3],
    /// Arm length l from centre to each rotor, m.
    pub arm_m: T,
    /// Rotor inertia Jr, kg·m² (gyroscopic term).
    pub rotor_inertia_kgm2: T,
    /// Thrust coefficient kf: thrust = kf·Ω², N·s².
    pub kf_ns2: T,
    /// Drag-moment coefficient kM: moment = kM·Ω², N·m·s².
    pub km_nms2: T,
    /// Translational drag (ktx, kty, ktz), N·s/m.
    pub kt_nspm: [T; 3],
    /// Rotational drag (krx, kry, krz), N·m·s.
    pub kr_nms: [T; 3],
    /// Rotor speed limit Ωmax, rad/s.
    pub omega_max_radps: T,
    /// Rotor first-order lag time constant τ, s (docs/book/src/model.md §6).
    pub rotor_tau_s: T,
    /// Rotor steady-state gain k (dimensionless, docs/book/src/model.md §6).
    pub rotor_gain: T,
}

impl VehicleParams<f64> {
    /// The OS4 quadrotor of thesis Appendix A (docs/book/src/model.md §2): the built-in default.
    pub const OS4: Self = Self {
        mass_kg: 0.65,
        gravity_mps2: 9.81,
        inertia_kgm2: [7.5e-3, 7.5e-3, 1.3e-2],
        arm_m: 0.23,
        rotor_inertia_kgm2: 6e-5,
        kf_ns2: 3.13e-5,
        km_nms2: 7.5e-7,
        kt_nspm: [0.1, 0.1, 0.15],
        kr_nms: [0.1, 0.1, 0.15],
        omega_max_radps: 600.0,
        rotor_tau_s: 0.178,
        rotor_gain: 0.936,
    };
}

impl<T: RealField + Copy> VehicleParams<T> {
    /// The OS4 parameters in this float type.
    pub fn os4() -> Self {
        VehicleParams::<f64>::OS4.cast()
    }

    /// Converts every parameter to another float type.
    pub fn cast<U: RealField + Copy>(&self) -> VehicleParams<U> {
        let c = |x: T| -> U { lit::<U>(nalgebra::try_convert::<T, f64>(x).unwrap_or(f64::NAN)) };
        let c3 = |v: [T; 3]| [c(v[0]), c(v[1]), c(v[2])];
        VehicleParams {
            mass_kg: c(self.mass_kg),
            gravity_mps2: c(self.gravity_mps2),
            inertia_kgm2: c3(self.inertia_kgm2),
            arm_m: c(self.arm_m),
            rotor_inertia_kgm2: c(self.rotor_inertia_kgm2),
            kf_ns2: c(self.kf_ns2),
            km_nms2: c(self.km_nms2),
            kt_nspm: c3(self.kt_nspm),
            kr_nms: c3(self.kr_nms),
            omega_max_radps: c(self.omega_max_radps),
            rotor_tau_s: c(self.rotor_tau_s),
            rotor_gain: c(self.rotor_gain),
        }
    }

    /// Hover thrust m·g, N.
    pub fn hover_thrust_n(&self) -> T {
        self.mass_kg * self.gravity_mps2
    }

    /// Rotor speed at hover, sqrt(m·g / 4kf), rad/s.
    pub fn hover_rotor_speed_radps(&self) -> T {
        (self.hover_thrust_n() / (lit::<T>(4.0) * self.kf_ns2)).sqrt()
    }

    /// The input box implied by Ωmax (docs/book/src/model.md §2): `0 ≤ U1 ≤ 4kfΩ²max`,
    /// `|U2|,|U3| ≤ kfΩ²max`, `|U4| ≤ 2kMΩ²max`, shrunk by 8 ulp of `T` so that
    /// a value inside stays inside the exact (`f64`) box after conversion.
    pub fn input_box(&self) -> InputBox<T> {
        let w2 = self.omega_max_radps * self.omega_max_radps;
        let shrink = T::one() - lit::<T>(8.0) * T::default_epsilon();
        let f = self.kf_ns2 * w2 * shrink;
        let m = lit::<T>(2.0) * self.km_nms2 * w2 * shrink;
        InputBox {
            lo: Vector4::new(T::zero(), -f, -f, -m),
            hi: Vector4::new(lit::<T>(4.0) * f, f, f, m),
        }
    }

    /// True if every parameter is finite and in its plausible range ([`PARAM_RANGES`]).
    pub fn is_valid(&self) -> bool {
        self.check().is_ok()
    }

    /// Checks every parameter against [`PARAM_RANGES`]; the first one out
    /// of range (or not finite) is named in the error with its value.
    pub fn check(&self) -> Result<(), ParamError> {
        let values = [
            self.mass_kg,
            self.gravity_mps2,
            self.inertia_kgm2[0],
            self.inertia_kgm2[1],
            self.inertia_kgm2[2],
            self.arm_m,
            self.rotor_inertia_kgm2,
            self.kf_ns2,
            self.km_nms2,
            self.kt_nspm[0],
            self.kt_nspm[1],
            self.kt_nspm[2],
            self.kr_nms[0],
            self.kr_nms[1],
            self.kr_nms[2],
            self.omega_max_radps,
            self.rotor_tau_s,
            self.rotor_gain,
        ];
        let f64_of = |v: T| nalgebra::try_convert::<T, f64>(v).unwrap_or(f64::NAN);
        for (&v, r) in values.iter().zip(PARAM_RANGES.iter()) {
            // Compared by `total_cmp`, integer work on the bits, where `<=`
            // on an f64 is a library call on an M4 (it has no f64 unit): the
            // same order for finite values once `-0` is `+0`, which `+ 0`
            // in `T` makes it.
            let x = f64_of(v + T::zero());
            if !(x.is_finite() && x.total_cmp(&r.lo).is_ge() && x.total_cmp(&r.hi).is_le()) {
                return Err(ParamError {
                    range: *r,
                    value: f64_of(v),
                });
            }
        }
        Ok(())
    }
}

/// A box `lo ≤ U ≤ hi` on the four inputs (N, N, N, N·m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InputBox<T: RealField + Copy> {
    /// Lower bounds.
    pub lo: Vector4<T>,
    /// Upper bounds.
    pub hi: Vector4<T>,
}

impl<T: RealField + Copy> InputBox<T> {
    /// Projects `u` onto the box. A NaN component maps to the box centre's
    /// clamp of zero (i.e. `clamp(0, lo, hi)`), so the result is always inside.
    pub fn clamp(&self, u: &Vector4<T>) -> Vector4<T> {
        let mut out = *u;
        for i in 0..4 {
            let v = if u[i].is_finite() { u[i] } else { T::zero() };
            out[i] = if v < self.lo[i] {
                self.lo[i]
            } else if v > self.hi[i] {
                self.hi[i]
            } else {
                v
            };
        }
        out
    }

    /// Largest excursion of `u` outside the box over the four channels, in
    /// each channel's own unit; 0 when inside. NaN counts as infinite.
    pub fn violation(&self, u: &Vector4<T>) -> T {
        let mut worst = T::zero();
        for i in 0..4 {
            if !u[i].is_finite() {
                return T::max_value().unwrap_or(T::one());
            }
            let e = (self.lo[i] - u[i]).max(u[i] - self.hi[i]);
            worst = worst.max(e);
        }
        worst
    }

    /// Largest magnitude each channel may take, `max(|lo|, |hi|)`: the
    /// normalisation used by the control-effort metric.
    pub fn scale(&self) -> Vector4<T> {
        self.lo.abs().sup(&self.hi.abs())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Field `i` of `p` (in [`PARAM_RANGES`]' order) set to `v`.
    fn with_field(p: &VehicleParams<f32>, i: usize, v: f32) -> VehicleParams<f32> {
        let mut q = *p;
        match i {
            0 => q.mass_kg = v,
            1 => q.gravity_mps2 = v,
            2..=4 => q.inertia_kgm2[i - 2] = v,
            5 => q.arm_m = v,
            6 => q.rotor_inertia_kgm2 = v,
            7 => q.kf_ns2 = v,
            8 => q.km_nms2 = v,
            9..=11 => q.kt_nspm[i - 9] = v,
            12..=14 => q.kr_nms[i - 12] = v,
            15 => q.omega_max_radps = v,
            16 => q.rotor_tau_s = v,
            17 => q.rotor_gain = v,
            _ => unreachable!("18 fields"),
        }
        q
    }

    /// The range test as plain f64 comparisons say it.
    fn in_range(v: f32, r: &ParamRange) -> bool {
        let x = f64::from(v);
        x.is_finite() && x >= r.lo && x <= r.hi
    }

    /// Each field's bounds, the f32 values either side of them, the zeros
    /// and the non-finite values.
    #[test]
    fn the_check_takes_what_f64_comparisons_take_at_every_bound() {
        let os4 = VehicleParams::<f32>::os4();
        for (i, r) in PARAM_RANGES.iter().enumerate() {
            let mut edges = vec![0.0, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MIN_POSITIVE];
            for b in [r.lo, r.hi] {
                let near = b as f32;
                edges.extend([near, near.next_up(), near.next_down(), -near]);
            }
            for v in edges {
                let got = with_field(&os4, i, v).check();
                assert_eq!(got.is_ok(), in_range(v, r), "{} = {v:e}", r.field);
                if let Err(e) = got {
                    assert_eq!(e.range.field, r.field);
                    assert_eq!(e.value.to_bits(), f64::from(v).to_bits(), "{} = {v:e}", r.field);
                }
            }
        }
    }

    proptest! {
        /// Any f32 bit pattern in any field: taken exactly when f64
        /// comparisons take it.
        #[test]
        fn the_check_takes_what_f64_comparisons_take(i in 0usize..18, bits in any::<u32>()) {
            let v = f32::from_bits(bits);
            let r = &PARAM_RANGES[i];
            prop_assert_eq!(with_field(&VehicleParams::<f32>::os4(), i, v).check().is_ok(), in_range(v, r));
        }
    }

    #[test]
    fn the_os4_is_plausible_and_each_implausible_field_is_named() {
        let os4 = VehicleParams::<f64>::OS4;
        assert_eq!(os4.check(), Ok(()));
        assert_eq!(VehicleParams::<f32>::os4().check(), Ok(()));
        // Field i set to something absurd must be reported as PARAM_RANGES[i]
        // (this also pins the order of `check`'s list to the table's).
        let setters: [fn(&mut VehicleParams<f64>, f64); 18] = [
            |p, v| p.mass_kg = v,
            |p, v| p.gravity_mps2 = v,
            |p, v| p.inertia_kgm2[0] = v,
            |p, v| p.inertia_kgm2[1] = v,
            |p, v| p.inertia_kgm2[2] = v,
            |p, v| p.arm_m = v,
            |p, v| p.rotor_inertia_kgm2 = v,
            |p, v| p.kf_ns2 = v,
            |p, v| p.km_nms2 = v,
            |p, v| p.kt_nspm[0] = v,
            |p, v| p.kt_nspm[1] = v,
            |p, v| p.kt_nspm[2] = v,
            |p, v| p.kr_nms[0] = v,
            |p, v| p.kr_nms[1] = v,
            |p, v| p.kr_nms[2] = v,
            |p, v| p.omega_max_radps = v,
            |p, v| p.rotor_tau_s = v,
            |p, v| p.rotor_gain = v,
        ];
        for (set, range) in setters.iter().zip(PARAM_RANGES.iter()) {
            for bad in [1e300, -1.0, f64::NAN, 1e-300_f64.min(range.lo * 0.5).max(-1.0)] {
                if bad >= range.lo && bad <= range.hi {
                    continue; // 0 is fine for the ones that may be 0
                }
                let mut p = os4;
                set(&mut p, bad);
                let e = p.check().expect_err(range.field);
                assert_eq!(e.range.field, range.field);
                assert!(e.to_string().contains(range.field), "{e}");
            }
        }
    }
}
