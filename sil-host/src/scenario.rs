//! Scenarios of docs/book/src/model.md §9 (`setpoint`, `circle` and `helix`)
//! and the aggressive `eight`, every number a parameter.

use fc_core::VehicleParams;
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

/// Which reference shape is flown.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ScenarioKind {
    /// Step to a fixed target position and heading.
    Setpoint,
    /// Horizontal circle at constant altitude, starting at the start point.
    Circle,
    /// The circle while climbing at a constant rate.
    Helix,
    /// A figure-8 at constant altitude through the start point: the
    /// lemniscate of Gerono `(A sin ωτ, (A/2) sin 2ωτ)` north and east,
    /// A = `radius_m`, one lap every `period_s` (1 m and 6 s by default:
    /// 1.48 m/s and 2.33 m/s² at peak), heading held.
    Eight,
}

impl ScenarioKind {
    /// Lower-case name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            ScenarioKind::Setpoint => "setpoint",
            ScenarioKind::Circle => "circle",
            ScenarioKind::Helix => "helix",
            ScenarioKind::Eight => "eight",
        }
    }
}

/// A scenario with all of its numbers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Scenario {
    /// Shape of the reference.
    pub kind: ScenarioKind,
    /// Start position, NED, m (hovering at rest, level).
    pub start_ned_m: [f64; 3],
    /// Start heading, rad.
    pub start_yaw_rad: f64,
    /// `setpoint`: target NED position, m.
    pub target_ned_m: [f64; 3],
    /// `setpoint`: target heading, rad.
    pub target_yaw_rad: f64,
    /// `circle`/`helix`: radius R, m; `eight`: its half-length A, m.
    pub radius_m: f64,
    /// `circle`/`helix`: period of one revolution, s; `eight`: of one lap.
    pub period_s: f64,
    /// `helix`: climb rate v (altitude gain per second), m/s.
    pub climb_rate_mps: f64,
    /// Flight length, s.
    pub duration_s: f64,
}

/// The reference at one instant, as a flat output (rotorpy's `flat_output`:
/// position and its derivatives up to jerk, heading and its rate); the
/// flight loop's own is [`fc_loop::planner::Reference`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlatOutput {
    /// NED position, m.
    pub pos: Vector3<f64>,
    /// NED velocity, m/s.
    pub vel: Vector3<f64>,
    /// NED acceleration, m/s².
    pub acc: Vector3<f64>,
    /// NED jerk, m/s³.
    pub jerk: Vector3<f64>,
    /// Heading ψ, rad.
    pub yaw: f64,
    /// Heading rate, rad/s.
    pub yaw_rate: f64,
}

/// The ranges [`Scenario::validate`] accepts.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Largest position coordinate and radius, m: a 10 km box (f32 keeps
    /// millimetres there).
    pub position_m: f64,
    /// Largest heading, rad (any heading is within ±π; this only keeps f32 sane).
    pub yaw_rad: f64,
    /// Largest climb rate, m/s.
    pub speed_mps: f64,
    /// Longest flight and reference period, s (one hour: the recorded
    /// trace, 100 rows a second, then stays under 70 MB).
    pub duration_s: f64,
}

/// The limits in force.
pub const LIMITS: Limits = Limits {
    position_m: 1.0e4,
    yaw_rad: 1.0e3,
    speed_mps: 100.0,
    duration_s: 3600.0,
};

impl Scenario {
    /// The docs/book/src/model.md §9 defaults for a kind.
    /// (`eight`: A = 1 m, a 6 s lap, 20 s.)
    pub fn default_for(kind: ScenarioKind) -> Self {
        let eight = kind == ScenarioKind::Eight;
        Self {
            kind,
            start_ned_m: [0.0, 0.0, -1.0],
            start_yaw_rad: 0.0,
            target_ned_m: [3.0, 2.0, -5.0],
            target_yaw_rad: 15f64.to_radians(),
            radius_m: if eight { 1.0 } else { 2.0 },
            period_s: if eight { 6.0 } else { 20.0 },
            climb_rate_mps: 0.05,
            duration_s: match kind {
                ScenarioKind::Setpoint | ScenarioKind::Eight => 20.0,
                _ => 100.0,
            },
        }
    }

    /// When the tracking error counts, s after the reference starts: the
    /// `eight`'s first lap is its entry (it starts at full speed from a
    /// hover), so its RMSE is taken from the end of that lap; the circle
    /// and helix from their start; a set-point is a step, not tracked
    /// (`None`).
    pub fn tracking_from_s(&self) -> Option<f64> {
        match self.kind {
            ScenarioKind::Eight => Some(self.period_s),
            ScenarioKind::Circle | ScenarioKind::Helix => Some(0.0),
            ScenarioKind::Setpoint => None,
        }
    }

    /// Reference at time `t` (s).
    pub fn reference(&self, t: f64) -> FlatOutput {
        let s0 = Vector3::from(self.start_ned_m);
        match self.kind {
            ScenarioKind::Setpoint => FlatOutput {
                pos: Vector3::from(self.target_ned_m),
                vel: Vector3::zeros(),
                acc: Vector3::zeros(),
                jerk: Vector3::zeros(),
                yaw: self.target_yaw_rad,
                yaw_rate: 0.0,
            },
            ScenarioKind::Circle | ScenarioKind::Helix => {
                let r = self.radius_m;
                let w = 2.0 * std::f64::consts::PI / self.period_s;
                let v = if self.kind == ScenarioKind::Helix {
                    self.climb_rate_mps
                } else {
                    0.0
                };
                let (s, c) = (w * t).sin_cos();
                FlatOutput {
                    pos: s0 + Vector3::new(r * s, r * (1.0 - c), -v * t),
                    vel: Vector3::new(r * w * c, r * w * s, -v),
                    acc: Vector3::new(-r * w * w * s, r * w * w * c, 0.0),
                    jerk: Vector3::new(-r * w * w * w * c, -r * w * w * w * s, 0.0),
                    yaw: self.start_yaw_rad,
                    yaw_rate: 0.0,
                }
            }
            ScenarioKind::Eight => {
                // North A sin θ, east (A/2) sin 2θ, θ = ωτ.
                let a = self.radius_m;
                let w = 2.0 * std::f64::consts::PI / self.period_s;
                let (s1, c1) = (w * t).sin_cos();
                let (s2, c2) = (2.0 * w * t).sin_cos();
                FlatOutput {
                    pos: s0 + Vector3::new(a * s1, 0.5 * a * s2, 0.0),
                    vel: Vector3::new(a * w * c1, a * w * c2, 0.0),
                    acc: Vector3::new(-a * w * w * s1, -2.0 * a * w * w * s2, 0.0),
                    jerk: Vector3::new(-a * w.powi(3) * c1, -4.0 * a * w.powi(3) * c2, 0.0),
                    yaw: self.start_yaw_rad,
                    yaw_rate: 0.0,
                }
            }
        }
    }

    /// Checks the numbers make a flyable scenario; the error names the field.
    ///
    /// The one rule for scenario values, from the command line and from
    /// files alike (the file loader calls it too): every value finite and
    /// within [`LIMITS`]' range, each error naming the field, its flag, the
    /// value and the range. What the vehicle can fly is
    /// [`Scenario::check_feasible`]'s.
    pub fn validate(&self) -> Result<(), String> {
        let within = |field: &str, v: f64, (lo, hi, open_lo): (f64, f64, bool)| {
            let above = if open_lo { v > lo } else { v >= lo };
            if v.is_finite() && above && v <= hi {
                Ok(())
            } else {
                Err(format!(
                    "{field} = {v:?} is out of range: must be in {}{lo}, {hi}]",
                    if open_lo { "(" } else { "[" }
                ))
            }
        };
        let pos = (-LIMITS.position_m, LIMITS.position_m, false);
        for (i, v) in self.start_ned_m.iter().enumerate() {
            within(&format!("start_ned_m[{i}], m"), *v, pos)?;
        }
        for (i, v) in self.target_ned_m.iter().enumerate() {
            within(&format!("target_ned_m[{i}] (--target X,Y,Z,YAW_DEG), m"), *v, pos)?;
        }
        let yaw = (-LIMITS.yaw_rad, LIMITS.yaw_rad, false);
        within("start_yaw, rad", self.start_yaw_rad, yaw)?;
        within("target_yaw (--target X,Y,Z,YAW_DEG), rad", self.target_yaw_rad, yaw)?;
        within("radius_m (--radius), m", self.radius_m, (0.0, LIMITS.position_m, true))?;
        within(
            "climb_rate_mps (--climb-rate), m/s",
            self.climb_rate_mps,
            (-LIMITS.speed_mps, LIMITS.speed_mps, false),
        )?;
        within("period_s (--period), s", self.period_s, (0.0, LIMITS.duration_s, true))?;
        within(
            "duration_s (--duration), s",
            self.duration_s,
            (0.0, LIMITS.duration_s, true),
        )?;
        Ok(())
    }

    /// Largest horizontal acceleration the reference asks for, m/s² (the
    /// circle's and helix's centripetal `r·ω²`; the eight's
    /// `A·ω²·max √(sin²θ + 4 sin²2θ)`, found on a 0.1° grid of θ; a
    /// set-point is a step and asks for none by itself).
    pub fn peak_horizontal_acceleration(&self) -> f64 {
        let w = 2.0 * std::f64::consts::PI / self.period_s;
        match self.kind {
            ScenarioKind::Setpoint => 0.0,
            ScenarioKind::Circle | ScenarioKind::Helix => self.radius_m * w * w,
            ScenarioKind::Eight => {
                let peak = (0..3600)
                    .map(|i| {
                        let th = f64::from(i) * std::f64::consts::PI / 1800.0;
                        (th.sin().powi(2) + 4.0 * (2.0 * th).sin().powi(2)).sqrt()
                    })
                    .fold(0.0, f64::max);
                self.radius_m * w * w * peak
            }
        }
    }

    /// Refuses a reference `vehicle` cannot fly: a peak horizontal
    /// acceleration above half of what its full thrust allows while
    /// holding its weight (`√((T_max/m)² − g²)`), naming both numbers.
    pub fn check_feasible(&self, vehicle: &VehicleParams<f64>) -> Result<(), String> {
        let t_over_m = vehicle.input_box().hi[0] / vehicle.mass_kg;
        let g = vehicle.gravity_mps2;
        let a_max = (t_over_m * t_over_m - g * g).max(0.0).sqrt();
        let a = self.peak_horizontal_acceleration();
        if a > 0.5 * a_max {
            return Err(format!(
                "the reference needs {a:.3e} m/s² of horizontal acceleration (radius {:?} m, period {:?} s); \
                 this vehicle has {a_max:.1} m/s² at full thrust and the limit is half of that, {:.1} m/s²: \
                 use a larger --period or a smaller --radius",
                self.radius_m,
                self.period_s,
                0.5 * a_max
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The eight's feed-forward is the derivative of its position (central
    /// differences, an independent computation of each), it passes through
    /// its start and closes after one lap.
    #[test]
    fn the_eights_derivatives_are_those_of_its_path() {
        let sc = Scenario::default_for(ScenarioKind::Eight);
        let h = 1e-4;
        for i in 0..60 {
            let t = 0.1 * f64::from(i) + 0.05;
            let (m, r, p) = (sc.reference(t - h), sc.reference(t), sc.reference(t + h));
            let fd = |a: Vector3<f64>, b: Vector3<f64>| (b - a) / (2.0 * h);
            assert!((fd(m.pos, p.pos) - r.vel).norm() < 1e-6, "velocity at {t}");
            assert!((fd(m.vel, p.vel) - r.acc).norm() < 1e-6, "acceleration at {t}");
            assert!((fd(m.acc, p.acc) - r.jerk).norm() < 1e-5, "jerk at {t}");
            assert_eq!((r.pos[2], r.yaw, r.yaw_rate), (-1.0, 0.0, 0.0), "level, heading held");
        }
        let start = Vector3::from(sc.start_ned_m);
        assert!((sc.reference(0.0).pos - start).norm() < 1e-12);
        assert!((sc.reference(sc.period_s).pos - start).norm() < 1e-12);
        // Half a lap out: A sin(π/2) north, (A/2) sin π east.
        assert!((sc.reference(1.5).pos - start - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        assert_eq!(sc.tracking_from_s(), Some(6.0));
    }

    /// The figures for A = 1 m and a 6 s lap: 1.48 m/s at peak (the
    /// crossing, √2·Aω), and the peak acceleration found on a fine grid
    /// (2.33 m/s²); the Crazyflie can fly it.
    #[test]
    fn the_eight_peaks_at_1_48_m_per_s() {
        let sc = Scenario::default_for(ScenarioKind::Eight);
        let speed = (0..6000)
            .map(|i| sc.reference(f64::from(i) * 1e-3).vel.norm())
            .fold(0.0, f64::max);
        assert!((speed - 1.4810).abs() < 1e-3, "{speed}");
        let acc = (0..6000)
            .map(|i| sc.reference(f64::from(i) * 1e-3).acc.norm())
            .fold(0.0, f64::max);
        assert!((sc.peak_horizontal_acceleration() - acc).abs() < 1e-3, "{acc}");
        assert!((acc - 2.3303).abs() < 1e-3, "{acc}");
        sc.validate().unwrap();
        let cf = crate::config::load_vehicle(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../vehicles/crazyflie-rotorpy.toml"),
        )
        .unwrap();
        sc.check_feasible(&cf).unwrap();
    }
}
