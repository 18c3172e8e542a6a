//! The flight stack's telemetry snapshot: what the loop shows of itself at
//! one instant, taken once and encoded by each protocol its own way (CRTP's
//! log variables, declared beside their getters in `fc-crtp`).

use crate::Loop;
use nalgebra::Vector3;

/// The loop's state at one instant. Without an estimate (the navigator
/// aligning) the estimate's fields are zero.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Snapshot {
    /// The navigator has an estimate.
    pub estimated: bool,
    /// Position, NED about home, m.
    pub pos_ned_m: Vector3<f32>,
    /// Velocity, NED, m/s.
    pub vel_ned_mps: Vector3<f32>,
    /// Roll, pitch, yaw (body FRD against NED, ZYX), rad.
    pub euler_rad: Vector3<f32>,
    /// The estimate's position variances (north, east, down), m².
    pub pos_var_m2: Vector3<f32>,
    /// The set-point's position, NED, m.
    pub setpoint_ned_m: Vector3<f32>,
    /// The collective thrust U1 of every rotor at its largest speed, N.
    pub u1_max_n: f32,
}

impl Loop {
    /// The telemetry snapshot now.
    pub fn snapshot(&self) -> Snapshot {
        let p = self.vehicle();
        let mut s = Snapshot {
            setpoint_ned_m: self.setpoint().pos_ned_m,
            u1_max_n: 4.0 * p.kf_ns2 * p.omega_max_radps * p.omega_max_radps,
            ..Snapshot::default()
        };
        if let Some(e) = self.navigator().estimate() {
            let cov = self.navigator().estimator().covariance();
            s.estimated = true;
            s.pos_ned_m = e.pos_ned_m;
            s.vel_ned_mps = e.vel_ned_mps;
            s.euler_rad = e.euler();
            s.pos_var_m2 = Vector3::new(cov[(0, 0)], cov[(1, 1)], cov[(2, 2)]);
        }
        s
    }
}
