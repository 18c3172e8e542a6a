//! `sil-host sweep`: Monte Carlo robustness. Every controller flies the same
//! scenario against many true vehicles that differ from the one it was
//! designed for (mass, inertia, drag, rotor lag drawn uniformly in the given
//! ranges from a seeded generator), and the sweep reports the success rate
//! (no divergence, always within a tube around the reference) and the
//! position-RMSE percentiles, with a figure of the RMSE distributions.

use crate::figures::{self, Figure, Panel, Plot, Series};
use crate::flight::{fly, FlightConfig, Uncertainty};
use crate::noise::SplitMix;
use crate::scenario::Scenario;
use crate::study::{label, VARIANTS};
use anyhow::{bail, Context, Result};
use fc_core::AttitudeForm;
use rayon::prelude::*;
use serde::Serialize;
use std::fmt::Write;
use std::path::PathBuf;

/// Ranges of the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct SweepOptions {
    /// Number of vehicles drawn.
    pub samples: usize,
    /// Seed of the generator (same seed, same vehicles).
    pub seed: u64,
    /// Mass within ± this fraction of nominal.
    pub mass_frac: f64,
    /// Each principal inertia within ± this fraction.
    pub inertia_frac: f64,
    /// Every drag coefficient within ± this fraction.
    pub drag_frac: f64,
    /// Rotor lag time constant drawn in [0, this] s (0: no lag).
    pub lag_max_s: f64,
    /// A flight succeeds if it never strays farther than this from the reference, m.
    pub tube_m: f64,
    /// What is flown (the base of every flight).
    #[serde(skip)]
    pub base: Scenario,
    /// Vehicle the controllers are designed for.
    #[serde(skip)]
    pub vehicle: fc_core::VehicleParams<f64>,
    /// Output directory.
    #[serde(skip)]
    pub out: PathBuf,
    /// Progress bar.
    #[serde(skip)]
    pub progress: bool,
}

/// The vehicles of a sweep, in order.
pub fn draw(o: &SweepOptions) -> Vec<Uncertainty> {
    let mut g = SplitMix(o.seed);
    (0..o.samples)
        .map(|_| {
            let s = |g: &mut SplitMix, f: f64| g.uniform(1.0 - f, 1.0 + f);
            let mass_scale = s(&mut g, o.mass_frac);
            let inertia_scale = [
                s(&mut g, o.inertia_frac),
                s(&mut g, o.inertia_frac),
                s(&mut g, o.inertia_frac),
            ];
            let drag_scale = s(&mut g, o.drag_frac);
            let tau = g.uniform(0.0, o.lag_max_s);
            Uncertainty {
                mass_scale,
                inertia_scale,
                drag_scale,
                rotor_tau_s: (o.lag_max_s > 0.0).then_some(tau),
            }
        })
        .collect()
}

/// One flight of the sweep.
#[derive(Debug, Clone, Serialize)]
pub struct SweepFlight {
    /// Sample index.
    pub sample: usize,
    /// The true vehicle's deviation.
    pub uncertainty: Uncertainty,
    /// 3-D position RMSE, m.
    pub rmse_m: f64,
    /// Largest distance from the reference, m.
    pub max_error_m: f64,
    /// No divergence and inside the tube.
    pub success: bool,
}

/// One controller's results.
#[derive(Debug, Clone, Serialize)]
pub struct SweepRow {
    /// Controller label.
    pub controller: String,
    /// Share of successful flights, %.
    pub success_pct: f64,
    /// RMSE percentiles p50, p90, p99 and the maximum over all flights, m.
    pub rmse_percentiles_m: [f64; 4],
    /// Every flight.
    pub flights: Vec<SweepFlight>,
}

/// Percentile `p` (0–100) by linear interpolation of the sorted values.
pub fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let x = (p / 100.0) * (sorted.len() - 1) as f64;
    let (i, f) = (x.floor() as usize, x - x.floor());
    let j = (i + 1).min(sorted.len() - 1);
    sorted[i] * (1.0 - f) + sorted[j] * f
}

fn controllers(base: &Scenario, vehicle: &fc_core::VehicleParams<f64>) -> Vec<FlightConfig> {
    let mut out = Vec::new();
    for (fam, preset) in VARIANTS {
        for model in AttitudeForm::ALL {
            let mut c = FlightConfig::new(fam, model, *base);
            c.spec.preset = preset;
            c.vehicle = *vehicle;
            out.push(c);
        }
    }
    out
}

/// Runs the sweep.
pub fn run(o: &SweepOptions) -> Result<Vec<SweepRow>> {
    // Refuse an unusable destination before flying.
    crate::record::prepare_output_dir(&o.out)?;
    if o.samples == 0 {
        bail!("--samples must be at least 1");
    }
    for (name, v) in [
        ("mass", o.mass_frac),
        ("inertia", o.inertia_frac),
        ("drag", o.drag_frac),
    ] {
        if !(v.is_finite() && (0.0..0.95).contains(&v)) {
            bail!("--{name}-pct must be in [0, 95), got {}", v * 100.0);
        }
    }
    let lag_ok = o.lag_max_s.is_finite() && o.lag_max_s >= 0.0;
    let tube_ok = o.tube_m.is_finite() && o.tube_m > 0.0;
    if !lag_ok || !tube_ok {
        bail!("--lag-max-s must be ≥ 0 and --tube-m > 0");
    }
    let vehicles = draw(o);
    let ctrls = controllers(&o.base, &o.vehicle);
    let jobs: Vec<(usize, usize)> = (0..ctrls.len())
        .flat_map(|c| (0..vehicles.len()).map(move |s| (c, s)))
        .collect();
    let bar = crate::study::progress_bar(jobs.len(), "flights", o.progress);
    let flights: Vec<(usize, SweepFlight)> = jobs
        .par_iter()
        .map(|&(c, s)| {
            let mut cfg = ctrls[c];
            cfg.uncertainty = Some(vehicles[s]);
            bar.set_message(format!("{} vehicle {s}", label(&cfg)));
            let r = fly(&cfg).with_context(|| format!("{} vehicle {s}", label(&cfg)))?;
            bar.inc(1);
            let tr = &r.trace;
            let d: Vec<f64> = tr
                .actual
                .iter()
                .zip(&tr.reference)
                .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt())
                .collect();
            let rmse = (d.iter().map(|v| v * v).sum::<f64>() / d.len().max(1) as f64).sqrt();
            let max = d.iter().copied().fold(0.0, f64::max);
            let rmse = if r.diverged { f64::INFINITY } else { rmse };
            Ok((
                c,
                SweepFlight {
                    sample: s,
                    uncertainty: vehicles[s],
                    rmse_m: rmse,
                    max_error_m: if r.diverged { f64::INFINITY } else { max },
                    success: !r.diverged && max <= o.tube_m,
                },
            ))
        })
        .collect::<Result<_>>()?;
    bar.finish_and_clear();
    Ok(ctrls
        .iter()
        .enumerate()
        .map(|(c, cfg)| {
            let fl: Vec<SweepFlight> = flights.iter().filter(|f| f.0 == c).map(|f| f.1.clone()).collect();
            let mut r: Vec<f64> = fl.iter().map(|f| f.rmse_m).collect();
            r.sort_by(f64::total_cmp);
            SweepRow {
                controller: label_short(cfg),
                success_pct: 100.0 * fl.iter().filter(|f| f.success).count() as f64 / fl.len().max(1) as f64,
                rmse_percentiles_m: [
                    percentile(&r, 50.0),
                    percentile(&r, 90.0),
                    percentile(&r, 99.0),
                    r.last().copied().unwrap_or(f64::NAN),
                ],
                flights: fl,
            }
        })
        .collect())
}

fn label_short(cfg: &FlightConfig) -> String {
    format!("{} {}", cfg.spec.title(), cfg.spec.form.name())
}

/// Writes `DIR/sweep.md`, `DIR/sweep.json` and the RMSE-distribution figure.
pub fn write(o: &SweepOptions, rows: &[SweepRow]) -> Result<PathBuf> {
    std::fs::create_dir_all(&o.out).with_context(|| format!("creating {}", o.out.display()))?;
    let fig = Figure {
        stem: "sweep_rmse".into(),
        title: format!(
            "Robustness: position RMSE over {} vehicles (mass ±{:.0} %, inertia ±{:.0} %, drag ±{:.0} %, lag ≤ {} s)",
            o.samples,
            100.0 * o.mass_frac,
            100.0 * o.inertia_frac,
            100.0 * o.drag_frac,
            o.lag_max_s
        ),
        plot: Plot::Panels(vec![Panel::new(
            format!(
                "position RMSE (m); flights beyond {:.1} m (3 × tube) are off the axis",
                3.0 * o.tube_m
            ),
            "share of vehicles with RMSE ≤ x",
            rows.iter()
                .enumerate()
                .map(|(i, r)| {
                    let clip = 3.0 * o.tube_m;
                    let mut v: Vec<f64> = r.flights.iter().map(|f| f.rmse_m).filter(|v| *v <= clip).collect();
                    v.sort_by(f64::total_cmp);
                    let n = r.flights.len().max(1) as f64;
                    let pts = v.iter().enumerate().map(|(k, x)| (*x, (k + 1) as f64 / n)).collect();
                    Series::line(r.controller.clone(), pts, i)
                })
                .collect(),
        )]),
    };
    figures::write(&o.out, &fig)?;
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# Robustness sweep\n\nGenerated by `sil-host sweep --samples {} --seed {}`: every controller flies `{}` \
         ({} s) against {} true vehicles drawn uniformly: mass ±{:.0} %, each inertia ±{:.0} %, drag ±{:.0} %, \
         rotor lag τ in [0, {}] s. Success: no divergence and never farther than {} m from the reference. RMSE: \
         3-D position error; a diverged flight counts as infinite.\n",
        o.samples,
        o.seed,
        o.base.kind.name(),
        o.base.duration_s,
        o.samples,
        100.0 * o.mass_frac,
        100.0 * o.inertia_frac,
        100.0 * o.drag_frac,
        o.lag_max_s,
        o.tube_m
    );
    let _ = writeln!(
        md,
        "| controller | success % | RMSE p50 m | RMSE p90 m | RMSE p99 m | RMSE max m |\n|---|---|---|---|---|---|"
    );
    for r in rows {
        let p = r.rmse_percentiles_m;
        let _ = writeln!(
            md,
            "| {} | {:.1} | {:.3} | {:.3} | {:.3} | {:.3} |",
            r.controller, r.success_pct, p[0], p[1], p[2], p[3]
        );
    }
    let _ = writeln!(
        md,
        "\n![RMSE distribution per controller](sweep_rmse.svg)\n\n[PNG](sweep_rmse.png) · [SVG](sweep_rmse.svg) · \
         [every flight (JSON)](sweep.json)"
    );
    let path = o.out.join("sweep.md");
    std::fs::write(&path, &md).with_context(|| format!("writing {}", path.display()))?;
    let json = serde_json::json!({ "options": o, "controllers": rows });
    std::fs::write(o.out.join("sweep.json"), serde_json::to_string_pretty(&json)? + "\n")?;
    std::fs::write(
        o.out.join("sweep.html"),
        crate::html::markdown_to_html(&md, "Robustness sweep", &o.out),
    )?;
    Ok(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts(seed: u64) -> SweepOptions {
        SweepOptions {
            samples: 200,
            seed,
            mass_frac: 0.2,
            inertia_frac: 0.3,
            drag_frac: 0.5,
            lag_max_s: 0.1,
            tube_m: 1.0,
            base: Scenario::default_for(crate::scenario::ScenarioKind::Helix),
            vehicle: fc_core::VehicleParams::OS4,
            out: PathBuf::from("/nonexistent"),
            progress: false,
        }
    }

    #[test]
    fn draws_are_seeded_and_inside_the_ranges() {
        assert_eq!(draw(&opts(7)), draw(&opts(7)));
        assert_ne!(draw(&opts(7)), draw(&opts(8)));
        let d = draw(&opts(7));
        for u in &d {
            assert!((0.8..=1.2).contains(&u.mass_scale));
            assert!(u.inertia_scale.iter().all(|s| (0.7..=1.3).contains(s)));
            assert!((0.5..=1.5).contains(&u.drag_scale));
            assert!(u.rotor_tau_s.is_some_and(|t| (0.0..=0.1).contains(&t)));
        }
        // Uniform: the mean mass scale of 200 draws is near 1 (σ of the mean ≈ 0.008).
        let mean = d.iter().map(|u| u.mass_scale).sum::<f64>() / d.len() as f64;
        assert!((mean - 1.0).abs() < 0.03, "{mean}");
    }

    #[test]
    fn percentiles() {
        let v = [1.0, 2.0, 3.0, 4.0, 5.0];
        assert_eq!(percentile(&v, 50.0), 3.0);
        assert_eq!(percentile(&v, 100.0), 5.0);
        assert!((percentile(&v, 90.0) - 4.6).abs() < 1e-12);
    }
}
