//! Flight metrics of docs/book/src/model.md §10, computed online while a flight is
//! flown ([`MetricsAccumulator`]) or from a recorded trace.

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
    /// 3-D position RMSE from [`MetricsAccumulator::tracking_from`]'s time
    /// on, m (`None` before it or when not asked for).
    pub tracking_rmse_m: Option<f64>,
    /// Largest 3-D position error over the same span, m.
    pub tracking_worst_m: Option<f64>,
}

impl FlightMetrics {
    /// Position RMSE over the flight, m: the three axes' RMSE combined
    /// (the RMS of the 3-D position error).
    pub fn position_rmse_m(&self) -> f64 {
        (self.x.rmse_m.powi(2) + self.y.rmse_m.powi(2) + self.z.rmse_m.powi(2)).sqrt()
    }
}

/// Axis metrics computed online, one sample at a time, so a flight of any
/// length needs no trace in memory. [`axis_metrics`] is the same on stored
/// samples. A step is detected when the reference is constant and differs
/// from the first measured value.
#[derive(Debug, Clone, Copy, Default)]
pub struct AxisAccumulator {
    n: usize,
    sum_sq: f64,
    t0: f64,
    y0: f64,
    r0: f64,
    rmin: f64,
    rmax: f64,
    /// From when the error has stayed inside the band (around `r0`), if it has.
    settled_from: Option<f64>,
    last_outside: bool,
    /// Largest excursion past `r0` in the direction of the step.
    past: f64,
}

impl AxisAccumulator {
    /// Adds the sample `y` (measured) against `r` (reference) at time `t`, s.
    pub fn push(&mut self, t: f64, y: f64, r: f64) {
        if self.n == 0 {
            *self = AxisAccumulator {
                t0: t,
                y0: y,
                r0: r,
                rmin: r,
                rmax: r,
                settled_from: Some(t),
                ..Self::default()
            };
        }
        self.n += 1;
        self.sum_sq += (y - r).powi(2);
        self.rmin = self.rmin.min(r);
        self.rmax = self.rmax.max(r);
        // Tracked as if the reference were the constant r0; used only if it was.
        let step = self.r0 - self.y0;
        if self.last_outside {
            self.settled_from = Some(t);
        }
        self.last_outside = (y - self.r0).abs() > SETTLING_BAND * step.abs();
        if self.last_outside {
            self.settled_from = None;
        }
        self.past = self.past.max((y - self.r0) * step.signum());
    }

    /// The metrics of the samples pushed so far.
    pub fn metrics(&self) -> AxisMetrics {
        if self.n == 0 {
            return AxisMetrics {
                rmse_m: 0.0,
                rmse_pct: 0.0,
                settling_s: None,
                overshoot_pct: None,
            };
        }
        let rmse = (self.sum_sq / self.n as f64).sqrt();
        let range = self.rmax - self.rmin;
        let constant = range <= 1e-12;
        // Reference range, or the step from the start where the reference is constant.
        let span = if constant { (self.rmax - self.y0).abs() } else { range };
        let rmse_pct = 100.0 * rmse / if span > 1e-9 { span } else { 1.0 };
        let step = self.r0 - self.y0;
        let (settling_s, overshoot_pct) = if constant && step.abs() > 1e-9 {
            (
                self.settled_from.map(|s| s - self.t0),
                Some(100.0 * self.past / step.abs()),
            )
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
}

/// Axis metrics for stored samples `y` (actual) against `r` (reference) at
/// times `t`, the first sample being the flight's start. See [`AxisAccumulator`].
pub fn axis_metrics(t: &[f64], y: &[f64], r: &[f64]) -> AxisMetrics {
    let mut acc = AxisAccumulator::default();
    for ((&t, &y), &r) in t.iter().zip(y).zip(r) {
        acc.push(t, y, r);
    }
    acc.metrics()
}

/// All of a flight's metrics computed online: push one sample per record
/// row with [`MetricsAccumulator::push`], read them with
/// [`MetricsAccumulator::metrics`]. Memory is constant in the flight's length.
#[derive(Debug, Clone, Copy)]
pub struct MetricsAccumulator {
    axes: [AxisAccumulator; 4],
    bx: InputBox<f64>,
    scale: nalgebra::Vector4<f64>,
    uh: nalgebra::Vector4<f64>,
    effort_sq: f64,
    inputs: usize,
    violation: f64,
    last_error_m: f64,
    /// From when the tracking error counts, s; its sum of squares, samples
    /// and largest value.
    track_from_s: f64,
    track: (f64, usize, f64),
}

impl MetricsAccumulator {
    /// An empty flight of the controller's nominal vehicle `p` (for the
    /// hover input and the input box).
    pub fn new(p: &VehicleParams<f64>) -> Self {
        let bx: InputBox<f64> = p.input_box();
        MetricsAccumulator {
            axes: [AxisAccumulator::default(); 4],
            scale: bx.scale(),
            bx,
            uh: hover_input(p),
            effort_sq: 0.0,
            inputs: 0,
            violation: 0.0,
            last_error_m: f64::NAN,
            track_from_s: f64::INFINITY,
            track: (0.0, 0, 0.0),
        }
    }

    /// Also measures the 3-D tracking error from `t_s` on, if given
    /// ([`FlightMetrics::tracking_rmse_m`]).
    pub fn tracking_from(mut self, t_s: Option<f64>) -> Self {
        self.track_from_s = t_s.unwrap_or(f64::INFINITY);
        self
    }

    /// Adds one sample at time `t`, s: measured and reference `[x, y, z, ψ]`
    /// (m, rad) and the commanded input as it left the controller.
    pub fn push(&mut self, t: f64, actual: &[f64; 4], reference: &[f64; 4], u_cmd: &[f64; 4]) {
        for (k, axis) in self.axes.iter_mut().enumerate() {
            axis.push(t, actual[k], reference[k]);
        }
        let u = nalgebra::Vector4::from(*u_cmd);
        self.effort_sq += (u - self.uh).component_div(&self.scale).norm_squared();
        self.inputs += 1;
        self.violation = self.violation.max(self.bx.violation(&u));
        self.last_error_m = ((actual[0] - reference[0]).powi(2)
            + (actual[1] - reference[1]).powi(2)
            + (actual[2] - reference[2]).powi(2))
        .sqrt();
        if t >= self.track_from_s - 1e-9 {
            self.track.0 += self.last_error_m * self.last_error_m;
            self.track.1 += 1;
            self.track.2 = self.track.2.max(self.last_error_m);
        }
    }

    /// The metrics of the samples pushed so far.
    pub fn metrics(&self) -> FlightMetrics {
        FlightMetrics {
            x: self.axes[0].metrics(),
            y: self.axes[1].metrics(),
            z: self.axes[2].metrics(),
            yaw: self.axes[3].metrics(),
            u_norm: if self.inputs == 0 {
                0.0
            } else {
                (self.effort_sq / self.inputs as f64).sqrt()
            },
            max_box_violation: self.violation,
            final_error_m: self.last_error_m,
            tracking_rmse_m: (self.track.1 > 0).then(|| (self.track.0 / self.track.1 as f64).sqrt()),
            tracking_worst_m: (self.track.1 > 0).then_some(self.track.2),
        }
    }
}

/// All metrics of a stored trace, with `p` the controller's nominal vehicle
/// (for the hover input and the input box) and the tracking error counted
/// from `tracking_from_s` (the scenario's
/// [`tracking_from_s`](crate::scenario::Scenario::tracking_from_s)); the
/// same as pushing every sample into a [`MetricsAccumulator`].
pub fn flight_metrics(trace: &Trace, p: &VehicleParams<f64>, tracking_from_s: Option<f64>) -> FlightMetrics {
    let mut acc = MetricsAccumulator::new(p).tracking_from(tracking_from_s);
    for (((t, a), r), u) in trace
        .t
        .iter()
        .zip(&trace.actual)
        .zip(&trace.reference)
        .zip(&trace.u_cmd)
    {
        acc.push(*t, a, r, u);
    }
    acc.metrics()
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
        let m = axis_metrics(&t, &y, &r);
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
        let m = axis_metrics(&t, &y, &r);
        let want = 100.0 * (-std::f64::consts::PI * z / (1.0 - z * z).sqrt()).exp();
        assert!((m.overshoot_pct.unwrap() - want).abs() < 0.05, "{m:?} vs {want}");
        assert!(m.settling_s.unwrap() > 3.0 && m.settling_s.unwrap() < 5.0);
    }

    #[test]
    fn a_step_still_outside_the_band_at_the_end_has_not_settled() {
        let t = grid(4, 1.0);
        // Step 0 → 1: inside the band at t = 2, outside again at the end.
        let m = axis_metrics(&t, &[0.0, 0.5, 1.0, 1.1], &[1.0; 4]);
        assert_eq!(m.settling_s, None);
        assert!((m.overshoot_pct.unwrap() - 10.0).abs() < 1e-9);
        // Back inside at the end: settled from the first of the last run inside.
        let m = axis_metrics(&t, &[0.0, 1.1, 1.0, 1.01], &[1.0; 4]);
        assert_eq!(m.settling_s, Some(2.0));
        // A moving reference has no step.
        let m = axis_metrics(&t, &[0.0; 4], &[1.0, 1.0, 1.0, 1.5]);
        assert_eq!((m.settling_s, m.overshoot_pct), (None, None));
    }

    #[test]
    fn tracking_rmse_pct_uses_reference_range() {
        let t = grid(1000, 0.01);
        let r: Vec<f64> = t.iter().map(|t| 2.0 * t.sin()).collect();
        let y: Vec<f64> = r.iter().map(|v| v + 0.1).collect();
        let m = axis_metrics(&t, &y, &r);
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
        let m = flight_metrics(&tr, &p, None);
        assert!((m.max_box_violation - 0.5).abs() < 1e-9);
        let second = ((11.768f64) / 11.268).powi(2);
        assert!((m.u_norm - (second / 2.0).sqrt()).abs() < 1e-9);
        assert_eq!(m.final_error_m, 0.0);
    }
}
