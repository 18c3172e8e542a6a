//! Disturbances of docs/book/src/model.md §9: `wind` (earth-frame force and body moment) and
//! `mismatch` (the plant differs from the controller's model).

use fc_core::{Disturbance, VehicleParams};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// Time at which the wind steps on, s.
pub const WIND_ONSET_S: f64 = 5.0;

/// Which disturbances act on a flight. Parsed from `none`, `wind`,
/// `mismatch` or `wind,mismatch`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DisturbanceSet {
    /// Wind force and moment steps from t = 5 s plus a 0.5 Hz gust on x.
    pub wind: bool,
    /// Mass +15 %, inertia +10 %, drag ×1.5, rotor lag on.
    pub mismatch: bool,
}

impl DisturbanceSet {
    /// No disturbance.
    pub const NONE: Self = Self {
        wind: false,
        mismatch: false,
    };

    /// The four combinations, in report order.
    pub const ALL: [Self; 4] = [
        Self::NONE,
        Self {
            wind: true,
            mismatch: false,
        },
        Self {
            wind: false,
            mismatch: true,
        },
        Self {
            wind: true,
            mismatch: true,
        },
    ];

    /// Force (NED, N) and moment (body FRD, N·m) acting at time `t` (s).
    /// Step `(0.5, −0.3, 0.2) N` and `(0.005, −0.005, 0.002) N·m` from 5 s, plus
    /// `0.2 N · sin(2π·0.5 Hz·(t − 5 s))` on x from 5 s.
    #[inline]
    pub fn at(&self, t: f64) -> Disturbance<f64> {
        if !self.wind || t < WIND_ONSET_S {
            return Disturbance::none();
        }
        let gust = 0.2 * (2.0 * std::f64::consts::PI * 0.5 * (t - WIND_ONSET_S)).sin();
        Disturbance {
            force_ned_n: Vector3::new(0.5 + gust, -0.3, 0.2),
            moment_body_nm: Vector3::new(0.005, -0.005, 0.002),
        }
    }

    /// The true vehicle under `mismatch`: mass +15 %, inertia +10 %,
    /// translational and rotational drag ×1.5 (rotor lag is switched on by
    /// the plant configuration).
    pub fn mismatched(p: &VehicleParams<f64>) -> VehicleParams<f64> {
        Uncertainty {
            mass_scale: 1.15,
            inertia_scale: [1.10; 3],
            drag_scale: 1.5,
            ..Uncertainty::NONE
        }
        .apply(p)
    }
}

/// A true vehicle that differs from the one the controller was designed for.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// Mass multiplier.
    pub mass_scale: f64,
    /// Multipliers of Ix, Iy, Iz.
    pub inertia_scale: [f64; 3],
    /// Multiplier of every translational and rotational drag coefficient.
    pub drag_scale: f64,
    /// Rotor lag time constant, s (the plant's rotor lag is on); `None`: no lag.
    pub rotor_tau_s: Option<f64>,
    /// Multiplier of the rotors' thrust coefficient `kf`.
    pub kf_scale: f64,
    /// A steady wind, NED, m/s: the air moves, so the translational drag
    /// acts on the velocity relative to it (a constant force `kt ⊙ wind`).
    pub wind_ned_mps: [f64; 3],
    /// The controller sees the state this long after it was true, s
    /// (sensing and link latency; rounded to whole plant steps).
    pub latency_s: f64,
}

impl Uncertainty {
    /// The vehicle as designed, in still air, seen at once.
    pub const NONE: Self = Self {
        mass_scale: 1.0,
        inertia_scale: [1.0; 3],
        drag_scale: 1.0,
        rotor_tau_s: None,
        kf_scale: 1.0,
        wind_ned_mps: [0.0; 3],
        latency_s: 0.0,
    };

    /// `p` with this uncertainty applied.
    pub fn apply(&self, p: &VehicleParams<f64>) -> VehicleParams<f64> {
        let mut q = *p;
        q.mass_kg *= self.mass_scale;
        for i in 0..3 {
            q.inertia_kgm2[i] *= self.inertia_scale[i];
            q.kt_nspm[i] *= self.drag_scale;
            q.kr_nms[i] *= self.drag_scale;
        }
        if let Some(t) = self.rotor_tau_s {
            q.rotor_tau_s = t;
        }
        q.kf_ns2 *= self.kf_scale;
        q
    }
}

impl fmt::Display for DisturbanceSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.wind, self.mismatch) {
            (false, false) => write!(f, "none"),
            (true, false) => write!(f, "wind"),
            (false, true) => write!(f, "mismatch"),
            (true, true) => write!(f, "wind,mismatch"),
        }
    }
}

impl FromStr for DisturbanceSet {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let mut d = Self::NONE;
        for part in s.split([',', '+']).map(str::trim) {
            match part {
                "none" | "" => {}
                "wind" => d.wind = true,
                "mismatch" => d.mismatch = true,
                other => {
                    return Err(format!(
                        "unknown disturbance '{other}': use none, wind, mismatch or wind,mismatch"
                    ))
                }
            }
        }
        Ok(d)
    }
}
