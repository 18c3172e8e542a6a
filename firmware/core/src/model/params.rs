//! Vehicle parameters (docs/model.md §2, OS4 quadrotor) and the input boxes derived from them.

use super::lit;
use nalgebra::{RealField, Vector4};

/// Physical parameters of the quadrotor. Units are in the field names.
#[derive(Debug, Clone, Copy, PartialEq)]
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
    /// Rotor first-order lag time constant τ, s (docs/model.md §6).
    pub rotor_tau_s: T,
    /// Rotor steady-state gain k (dimensionless, docs/model.md §6).
    pub rotor_gain: T,
}

impl VehicleParams<f64> {
    /// The OS4 quadrotor of thesis Appendix A (docs/model.md §2): the built-in default.
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

    /// The input box implied by Ωmax (docs/model.md §2): `0 ≤ U1 ≤ 4kfΩ²max`,
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

    /// True if every parameter is finite and the physical ones are positive.
    pub fn is_valid(&self) -> bool {
        let pos = [
            self.mass_kg,
            self.gravity_mps2,
            self.inertia_kgm2[0],
            self.inertia_kgm2[1],
            self.inertia_kgm2[2],
            self.arm_m,
            self.kf_ns2,
            self.km_nms2,
            self.omega_max_radps,
            self.rotor_tau_s,
            self.rotor_gain,
        ];
        let nonneg = [
            self.rotor_inertia_kgm2,
            self.kt_nspm[0],
            self.kt_nspm[1],
            self.kt_nspm[2],
            self.kr_nms[0],
            self.kr_nms[1],
            self.kr_nms[2],
        ];
        pos.iter().all(|x| x.is_finite() && *x > T::zero()) && nonneg.iter().all(|x| x.is_finite() && *x >= T::zero())
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
