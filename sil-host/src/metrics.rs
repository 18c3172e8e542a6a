//! Flight metrics of docs/model.md §10, computed from a recorded trace.

use fc_core::{hover_input, InputBox, VehicleParams};
use serde::{Deserialize, Serialize};

/// Fraction of the step size that defines "settled" (2 %).
pub const SETTLING_BAND: f64 = 0.02;

/// One recorded flight, one entry per sample (uniform sample time).
#[derive(Debug, Clone, Default)]
pub struct Trace {
    /// Time, s.
    pub t: Vec<f64>,
    /// Measured `[x, y, z, ψ]` (m, m, m, rad).
    pub actual: Vec<[f64; 4]>,
    /// Reference `[x, y, z, ψ]` (m, m, m, rad).
    pub reference: Vec<[f64; 4]>,
    /// Commanded inputs, as they left the controller.
    pub u_cmd: Vec<[f64; 4]>,
}

/// Metrics of one axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AxisMetrics {
    /// Root-mean-square tracking error (m for x, y, z; rad for yaw).
    pub rmse_m: f64,
    /// RMSE as % of the reference's range on the axis (of 1 unit when constant).
    pub rmse_pct: f64,
    /// First time after which the error stays within 2 % of the step size, s;
    /// `null` when the axis has no step (constant or moving reference) or never settles.
    pub settling_s: Option<f64>,
    /// Peak excursion past the target, % of the step size; `null` without a step.
    pub overshoot_pct: Option<f64>,
}

/// Metrics of a whole flight.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FlightMetrics {
    /// x (north) axis.
    pub x: AxisMetrics,
    /// y (east) axis.
    pub y: AxisMetrics,
    /// z (down) axis.
    pub z: AxisMetrics,
    /// Heading.
    pub yaw: AxisMetrics,
    /// RMS over time of `‖(U − Uhover) ./ scale‖`, scale = largest |bound| per channel.
    pub u_norm: f64,
    /// Largest commanded excursion outside the input box (own units; 0 = never).
    pub max_box_violation: f64,
    /// Position error at the end of the flight, m.
    pub final_error_m: f64,
}

impl FlightMetrics {
    /// Position RMSE over the flight, m: the three axes' RMSE combined
    /// (the RMS of the 3-D position error).
    pub fn position_rmse_m(&self) -> f64 {
        (self.x.rmse_m.powi(2) + self.y.rmse_m.powi(2) + self.z.rmse_m.powi(2)).sqrt()
    }
}

/// Axis metrics for samples `y` (actual) against `r` (reference) with the
/// flight's initial value `y0`. A step is detected when the reference is
/// constant and differs from `y0`.
pub fn axis_metrics(t: &[f64], y: &[f64], r: &[f64], y0: f64) -> AxisMetrics {
    let n = y.len().min(r.len()).min(t.len());
    if n == 0 {
        return AxisMetrics {
            rmse_m: 0.0,
            rmse_pct: 0.0,
            settling_s: None,
            overshoot_pct: None,
        };
    }
    let mse = (0..n).map(|i| (y[i] - r[i]).powi(2)).sum::<f64>() / n as f64;
    let rmse = mse.sqrt();
    let (rmin, rmax) = r[..n]
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(*v), b.max(*v)));
    let range = rmax - rmin;
    let constant = range <= 1e-12;
    // Reference range, or the step from the start where the reference is constant.
    let span = if constant { (rmax - y0).abs() } else { range };
    let rmse_pct = 100.0 * rmse / if span > 1e-9 { span } else { 1.0 };
    let step = rmax - y0;
    let (settling_s, overshoot_pct) = if constant && step.abs() > 1e-9 {
        let target = rmax;
        let band = SETTLING_BAND * step.abs();
        // Last sample outside the band; settled from the next one.
        let settled = match (0..n).rev().find(|&i| (y[i] - target).abs() > band) {
            None => Some(t[0]),
            Some(i) if i + 1 < n => Some(t[i + 1]),
            Some(_) => None,
        };
        let past = y[..n]
            .iter()
            .map(|v| (v - target) * step.signum())
            .fold(0.0f64, f64::max);
        (settled.map(|s| s - t[0]), Some(100.0 * past / step.abs()))
    } else {
        (None, None)
    };
    AxisMetrics {
        rmse_m: rmse,
        rmse_pct,
        settling_s,
        overshoot_pct,
    }
}

/// All metrics of a trace, with `p` the controller's nominal vehicle (for the
/// hover input and the input box).
pub fn flight_metrics(trace: &Trace, p: &VehicleParams<f64>) -> FlightMetrics {
    let col = |v: &[[f64; 4]], k: usize| v.iter().map(|s| s[k]).collect::<Vec<_>>();
    let axis = |k: usize| {
        let y = col(&trace.actual, k);
        let y0 = y.first().copied().unwrap_or(0.0);
        axis_metrics(&trace.t, &y, &col(&trace.reference, k), y0)
    };
    let bx: InputBox<f64> = p.input_box();
    let scale = bx.scale();
    let uh = hover_input(p);
    let mut acc = 0.0;
    let mut viol = 0.0f64;
    for u in &trace.u_cmd {
        let u = nalgebra::Vector4::from(*u);
        acc += (u - uh).component_div(&scale).norm_squared();
        viol = viol.max(bx.violation(&u));
    }
    let u_norm = if trace.u_cmd.is_empty() {
        0.0
    } else {
        (acc / trace.u_cmd.len() as f64).sqrt()
    };
    let final_error_m = match (trace.actual.last(), trace.reference.last()) {
        (Some(a), Some(r)) => ((a[0] - r[0]).powi(2) + (a[1] - r[1]).powi(2) + (a[2] - r[2]).powi(2)).sqrt(),
        _ => f64::NAN,
    };
    FlightMetrics {
        x: axis(0),
        y: axis(1),
        z: axis(2),
        yaw: axis(3),
        u_norm,
        max_box_violation: viol,
        final_error_m,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize, dt: f64) -> Vec<f64> {
        (0..n).map(|i| i as f64 * dt).collect()
    }

    #[test]
    fn first_order_step_settles_at_ln50_tau() {
        // y = 1 − e^{−t/τ}: error < 2 % from t = τ·ln 50; no overshoot.
        let tau = 0.5;
        let t = grid(10_001, 1e-3);
        let y: Vec<f64> = t.iter().map(|t| 1.0 - (-t / tau).exp()).collect();
        let r = vec![1.0; t.len()];
        let m = axis_metrics(&t, &y, &r, 0.0);
        let want = tau * 50f64.ln();
        assert!((m.settling_s.unwrap() - want).abs() < 2e-3, "{m:?}");
        assert_eq!(m.overshoot_pct, Some(0.0));
        // RMSE of e^{−t/τ} over [0, 10]: sqrt(τ/2 (1 − e^{−2T/τ}) / T).
        let rmse = (tau / 2.0 / 10.0).sqrt();
        assert!((m.rmse_m - rmse).abs() < 1e-3);
    }

    #[test]
    fn underdamped_overshoot_matches_formula() {
        // Second order with ζ = 0.5, ωn = 2: overshoot exp(−πζ/√(1−ζ²)) = 16.3 %.
        let (z, wn) = (0.5f64, 2.0f64);
        let wd = wn * (1.0 - z * z).sqrt();
        let t = grid(20_001, 1e-3);
        let step = -4.0; // a step downwards (like z in NED when climbing)
        let y: Vec<f64> = t
            .iter()
            .map(|t| {
                1.0 + step * (1.0 - (-z * wn * t).exp() * ((wd * t).cos() + z / (1.0 - z * z).sqrt() * (wd * t).sin()))
            })
            .collect();
        let r = vec![1.0 + step; t.len()];
        let m = axis_metrics(&t, &y, &r, 1.0);
        let want = 100.0 * (-std::f64::consts::PI * z / (1.0 - z * z).sqrt()).exp();
        assert!((m.overshoot_pct.unwrap() - want).abs() < 0.05, "{m:?} vs {want}");
        assert!(m.settling_s.unwrap() > 3.0 && m.settling_s.unwrap() < 5.0);
    }

    #[test]
    fn tracking_rmse_pct_uses_reference_range() {
        let t = grid(1000, 0.01);
        let r: Vec<f64> = t.iter().map(|t| 2.0 * t.sin()).collect();
        let y: Vec<f64> = r.iter().map(|v| v + 0.1).collect();
        let m = axis_metrics(&t, &y, &r, 0.0);
        assert!((m.rmse_m - 0.1).abs() < 1e-12);
        let range = r.iter().cloned().fold(f64::MIN, f64::max) - r.iter().cloned().fold(f64::MAX, f64::min);
        assert!((m.rmse_pct - 10.0 / range).abs() < 1e-9);
        assert_eq!(m.settling_s, None);
    }

    #[test]
    fn effort_and_box_violation() {
        let p = VehicleParams::OS4;
        let uh = hover_input(&p);
        let tr = Trace {
            t: vec![0.0, 0.1],
            actual: vec![[0.0; 4]; 2],
            reference: vec![[0.0; 4]; 2],
            u_cmd: vec![[uh[0], 0.0, 0.0, 0.0], [uh[0], 11.268 + 0.5, 0.0, 0.0]],
        };
        let m = flight_metrics(&tr, &p);
        assert!((m.max_box_violation - 0.5).abs() < 1e-9);
        let second = ((11.768f64) / 11.268).powi(2);
        assert!((m.u_norm - (second / 2.0).sqrt()).abs() < 1e-9);
        assert_eq!(m.final_error_m, 0.0);
    }
}
