//! Scenarios of docs/model.md §9: `setpoint`, `circle` and `helix`, every number a parameter.

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
}

impl ScenarioKind {
    /// Lower-case name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            ScenarioKind::Setpoint => "setpoint",
            ScenarioKind::Circle => "circle",
            ScenarioKind::Helix => "helix",
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
    /// `circle`/`helix`: radius R, m.
    pub radius_m: f64,
    /// `circle`/`helix`: period of one revolution, s.
    pub period_s: f64,
    /// `helix`: climb rate v (altitude gain per second), m/s.
    pub climb_rate_mps: f64,
    /// Flight length, s.
    pub duration_s: f64,
}

/// The reference at one instant: position, its first two derivatives, heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
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

impl Scenario {
    /// The docs/model.md §9 defaults for a kind.
    pub fn default_for(kind: ScenarioKind) -> Self {
        Self {
            kind,
            start_ned_m: [0.0, 0.0, -1.0],
            start_yaw_rad: 0.0,
            target_ned_m: [3.0, 2.0, -5.0],
            target_yaw_rad: 15f64.to_radians(),
            radius_m: 2.0,
            period_s: 20.0,
            climb_rate_mps: 0.05,
            duration_s: match kind {
                ScenarioKind::Setpoint => 20.0,
                _ => 100.0,
            },
        }
    }

    /// Reference at time `t` (s).
    pub fn reference(&self, t: f64) -> Reference {
        let s0 = Vector3::from(self.start_ned_m);
        match self.kind {
            ScenarioKind::Setpoint => Reference {
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
                Reference {
                    pos: s0 + Vector3::new(r * s, r * (1.0 - c), -v * t),
                    vel: Vector3::new(r * w * c, r * w * s, -v),
                    acc: Vector3::new(-r * w * w * s, r * w * w * c, 0.0),
                    jerk: Vector3::new(-r * w * w * w * c, -r * w * w * w * s, 0.0),
                    yaw: self.start_yaw_rad,
                    yaw_rate: 0.0,
                }
            }
        }
    }

    /// Checks the numbers make a flyable scenario; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        let finite = |name: &str, v: f64| {
            if v.is_finite() {
                Ok(())
            } else {
                Err(format!("{name} must be a finite number"))
            }
        };
        for (i, v) in self.start_ned_m.iter().enumerate() {
            finite(&format!("start_ned_m[{i}]"), *v)?;
        }
        for (i, v) in self.target_ned_m.iter().enumerate() {
            finite(&format!("target_ned_m[{i}]"), *v)?;
        }
        finite("radius_m", self.radius_m)?;
        finite("climb_rate_mps", self.climb_rate_mps)?;
        finite("target_yaw_rad", self.target_yaw_rad)?;
        if !(self.duration_s > 0.0 && self.duration_s.is_finite()) {
            return Err("duration_s must be positive".into());
        }
        if !(self.period_s > 0.0 && self.period_s.is_finite()) {
            return Err("period_s must be positive".into());
        }
        Ok(())
    }
}
