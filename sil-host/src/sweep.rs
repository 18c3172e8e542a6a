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
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::PathBuf;

/// Ranges of the sweep.
#[derive(Debug, Clone, Serialize, Deserialize)]
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
    /// Thrust coefficient within ± this fraction.
    pub kf_frac: f64,
    /// Steady horizontal wind of up to this speed, m/s, from a uniformly
    /// drawn direction.
    pub wind_max_mps: f64,
    /// Sensor latency drawn in [0, this] s.
    pub latency_max_s: f64,
    /// A flight succeeds if it never strays farther than this from the reference, m.
    pub tube_m: f64,
    /// What is flown (the base of every flight).
    pub base: Scenario,
    /// Vehicle the controllers are designed for.
    pub vehicle: fc_core::VehicleParams<f64>,
    /// Output directory.
    #[serde(skip)]
    pub out: PathBuf,
    /// Progress bar.
    #[serde(skip)]
    pub progress: bool,
}

impl SweepOptions {
    /// The defaults of `sil-host sweep` (issue 15's "harder, more honest"
    /// ranges): mass ±20 %, inertia ±30 %, drag ±50 %, rotor lag 0–0.2 s,
    /// thrust coefficient ±10 %, steady wind up to 3 m/s, latency 0–5 ms,
    /// 1 m tube, seed 1, 400 vehicles.
    pub fn defaults(base: Scenario, out: PathBuf) -> Self {
        Self {
            samples: 400,
            seed: 1,
            mass_frac: 0.2,
            inertia_frac: 0.3,
            drag_frac: 0.5,
            lag_max_s: 0.2,
            kf_frac: 0.1,
            wind_max_mps: 3.0,
            latency_max_s: 0.005,
            tube_m: 1.0,
            base,
            vehicle: fc_core::VehicleParams::OS4,
            out,
            progress: true,
        }
    }
}

/// Vehicle `index` of a sweep: its draw depends on the seed and the index
/// only (its own generator), so any slice of a sweep can be flown anywhere.
pub fn draw_one(o: &SweepOptions, index: usize) -> Uncertainty {
    let mut g = SplitMix(SplitMix(o.seed).next_u64() ^ SplitMix(!(index as u64)).next_u64());
    let s = |g: &mut SplitMix, f: f64| g.uniform(1.0 - f, 1.0 + f);
    let mass_scale = s(&mut g, o.mass_frac);
    let inertia_scale = [
        s(&mut g, o.inertia_frac),
        s(&mut g, o.inertia_frac),
        s(&mut g, o.inertia_frac),
    ];
    let drag_scale = s(&mut g, o.drag_frac);
    let tau = g.uniform(0.0, o.lag_max_s);
    let kf_scale = s(&mut g, o.kf_frac);
    let (speed, dir) = (g.uniform(0.0, o.wind_max_mps), g.uniform(0.0, std::f64::consts::TAU));
    let latency_s = g.uniform(0.0, o.latency_max_s);
    Uncertainty {
        mass_scale,
        inertia_scale,
        drag_scale,
        rotor_tau_s: (o.lag_max_s > 0.0).then_some(tau),
        kf_scale,
        wind_ned_mps: [speed * dir.cos(), speed * dir.sin(), 0.0],
        latency_s,
    }
}

/// The vehicles of a sweep, in order.
pub fn draw(o: &SweepOptions) -> Vec<Uncertainty> {
    (0..o.samples).map(|i| draw_one(o, i)).collect()
}

impl SweepOptions {
    /// Refuses ranges that make no vehicle, naming the flag.
    pub fn check(&self) -> Result<()> {
        for (name, v) in [
            ("mass", self.mass_frac),
            ("inertia", self.inertia_frac),
            ("drag", self.drag_frac),
            ("kf", self.kf_frac),
        ] {
            if !(v.is_finite() && (0.0..0.95).contains(&v)) {
                bail!("--{name}-pct must be in [0, 95), got {:?}", v * 100.0);
            }
        }
        for (flag, v, max) in [
            ("--lag-max-s", self.lag_max_s, 1.0),
            ("--wind-max", self.wind_max_mps, 30.0),
            ("--latency-max-ms", self.latency_max_s * 1e3, 100.0),
        ] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                bail!("{flag} must be in [0, {max}], got {v:?}");
            }
        }
        if !(self.tube_m.is_finite() && self.tube_m > 0.0) {
            bail!("--tube-m must be > 0, got {:?}", self.tube_m);
        }
        Ok(())
    }
}

/// A distance that is infinite for a diverged flight: JSON `null` then
/// (JSON has no infinity), read back as infinity.
mod finite_or_null {
    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        if v.is_finite() {
            s.serialize_f64(*v)
        } else {
            s.serialize_none()
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::INFINITY))
    }
}

/// One flight of the sweep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepFlight {
    /// Sample index.
    pub sample: usize,
    /// The true vehicle's deviation.
    pub uncertainty: Uncertainty,
    /// 3-D position RMSE, m (`null` in JSON when the flight diverged).
    #[serde(with = "finite_or_null")]
    pub rmse_m: f64,
    /// Largest distance from the reference, m (`null` when diverged).
    #[serde(with = "finite_or_null")]
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

/// Runs the sweep on this machine.
pub fn run(o: &SweepOptions) -> Result<Vec<SweepRow>> {
    // Refuse an unusable destination before flying.
    crate::record::prepare_output_dir(&o.out)?;
    let flights = fly_samples(o, |_| true)?;
    aggregate(o, flights)
}

/// Flies the slice `shard = (i, n)` of the sweep — the samples whose
/// index is `i` modulo `n` — and writes it as JSON lines to
/// `DIR/shard-I-of-N.jsonl`: a header with the options and the shard, then
/// one line per flight. Every sample's vehicle depends on the seed and its
/// index only, so the shards of one sweep can run on any machines, in any
/// order; [`merge`] puts them together.
pub fn run_shard(o: &SweepOptions, (i, n): (usize, usize)) -> Result<PathBuf> {
    if n == 0 || i >= n {
        bail!("--shard {i}/{n}: needs N ≥ 1 and 0 ≤ I < N");
    }
    crate::record::prepare_output_dir(&o.out)?;
    let flights = fly_samples(o, |s| s % n == i)?;
    let path = o.out.join(format!("shard-{i}-of-{n}.jsonl"));
    let mut text = serde_json::to_string(&ShardHeader {
        shard: [i, n],
        options: o.clone(),
    })? + "\n";
    for (c, f) in &flights {
        text += &serde_json::to_string(&ShardLine {
            controller: *c,
            flight: f.clone(),
        })?;
        text.push('\n');
    }
    std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    Ok(path)
}

/// The first line of a shard file.
#[derive(Debug, Serialize, Deserialize)]
struct ShardHeader {
    /// `[I, N]`.
    shard: [usize; 2],
    /// The sweep's options (the same in every shard of one sweep).
    options: SweepOptions,
}

/// Every other line of a shard file.
#[derive(Debug, Serialize, Deserialize)]
struct ShardLine {
    /// Index of the controller variant (the sweep's fixed order).
    controller: usize,
    /// The flight.
    flight: SweepFlight,
}

/// Reads every `*.jsonl` shard file in `dirs` and checks that they are the
/// shards `0..N` of one sweep (same options, each shard once) and hold every
/// (controller, sample) flight exactly once; returns the options (with
/// `out`) and the rows a one-machine run of the same sweep gives.
pub fn merge(dirs: &[PathBuf], out: PathBuf) -> Result<(SweepOptions, Vec<SweepRow>)> {
    let mut files = Vec::new();
    for d in dirs {
        for e in std::fs::read_dir(d).with_context(|| format!("reading {}", d.display()))? {
            let p = e?.path();
            if p.extension().is_some_and(|x| x == "jsonl") {
                files.push(p);
            }
        }
    }
    files.sort();
    if files.is_empty() {
        bail!("no shard files (*.jsonl) in {dirs:?}");
    }
    let mut opts: Option<SweepOptions> = None;
    let mut shards_seen: Vec<bool> = Vec::new();
    let mut flights = Vec::new();
    for f in &files {
        let text = std::fs::read_to_string(f).with_context(|| format!("reading {}", f.display()))?;
        let mut lines = text.lines();
        let h: ShardHeader = serde_json::from_str(lines.next().unwrap_or(""))
            .with_context(|| format!("{}: not a shard file (bad header)", f.display()))?;
        let [i, n] = h.shard;
        match &opts {
            None => {
                shards_seen = vec![false; n];
                opts = Some(h.options.clone());
            }
            Some(o) => {
                let same = serde_json::to_value(o)? == serde_json::to_value(&h.options)?;
                if !same || shards_seen.len() != n {
                    bail!(
                        "{}: shard of a different sweep (options or shard count differ)",
                        f.display()
                    );
                }
            }
        }
        if i >= n || std::mem::replace(&mut shards_seen[i], true) {
            bail!("{}: shard {i}/{n} is out of range or given twice", f.display());
        }
        for (k, l) in lines.enumerate() {
            let line: ShardLine =
                serde_json::from_str(l).with_context(|| format!("{}: line {}", f.display(), k + 2))?;
            flights.push((line.controller, line.flight));
        }
    }
    if let Some(missing) = shards_seen.iter().position(|s| !s) {
        bail!("shard {missing}/{} is missing", shards_seen.len());
    }
    let mut o = opts.expect("at least one file was read");
    o.out = out;
    let rows = aggregate(&o, flights)?;
    Ok((o, rows))
}

/// The ranges the vehicles are drawn from, in words (for tables' captions).
pub fn describe_ranges(o: &SweepOptions) -> String {
    format!(
        "mass ±{:.0} %, each inertia ±{:.0} %, drag ±{:.0} %, rotor lag τ in [0, {}] s, thrust coefficient ±{:.0} %, \
         a steady horizontal wind of up to {} m/s from any direction, sensor latency in [0, {}] ms",
        100.0 * o.mass_frac,
        100.0 * o.inertia_frac,
        100.0 * o.drag_frac,
        o.lag_max_s,
        100.0 * o.kf_frac,
        o.wind_max_mps,
        1e3 * o.latency_max_s,
    )
}

/// Flies every controller against the vehicles whose index passes `pick`,
/// on all cores; `(controller index, flight)` in (controller, sample) order.
fn fly_samples(o: &SweepOptions, pick: impl Fn(usize) -> bool) -> Result<Vec<(usize, SweepFlight)>> {
    if o.samples == 0 {
        bail!("--samples must be at least 1");
    }
    o.check()?;
    let ctrls = controllers(&o.base, &o.vehicle);
    let samples: Vec<usize> = (0..o.samples).filter(|s| pick(*s)).collect();
    let jobs: Vec<(usize, usize)> = (0..ctrls.len())
        .flat_map(|c| samples.iter().map(move |s| (c, *s)))
        .collect();
    let bar = crate::study::progress_bar(jobs.len(), "flights", o.progress);
    let log = ProgressLog::new(
        jobs.len(),
        o.progress && !std::io::IsTerminal::is_terminal(&std::io::stderr()),
    );
    let flights = jobs
        .par_iter()
        .map(|&(c, s)| {
            let mut cfg = ctrls[c];
            cfg.uncertainty = Some(draw_one(o, s));
            bar.set_message(format!("{} vehicle {s}", label(&cfg)));
            let r = fly(&cfg).with_context(|| format!("{} vehicle {s}", label(&cfg)))?;
            bar.inc(1);
            log.tick();
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
                    uncertainty: cfg.uncertainty.expect("set above"),
                    rmse_m: rmse,
                    max_error_m: if r.diverged { f64::INFINITY } else { max },
                    success: !r.diverged && max <= o.tube_m,
                },
            ))
        })
        .collect::<Result<_>>()?;
    bar.finish_and_clear();
    Ok(flights)
}

/// A progress line on standard error every 5 s (with the rate and an
/// ETA) when it is not a terminal — a batch job's log — where the bar
/// does not draw.
struct ProgressLog {
    total: usize,
    on: bool,
    t0: std::time::Instant,
    done: std::sync::atomic::AtomicUsize,
    last: std::sync::Mutex<std::time::Instant>,
}

impl ProgressLog {
    fn new(total: usize, on: bool) -> Self {
        let now = std::time::Instant::now();
        Self {
            total,
            on,
            t0: now,
            done: 0.into(),
            last: std::sync::Mutex::new(now),
        }
    }

    fn tick(&self) {
        let done = self.done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        if !self.on {
            return;
        }
        let Ok(mut last) = self.last.lock() else { return };
        if last.elapsed().as_secs_f64() < 5.0 && done < self.total {
            return;
        }
        *last = std::time::Instant::now();
        let t = self.t0.elapsed().as_secs_f64();
        let rate = done as f64 / t.max(1e-9);
        let eta = (self.total - done) as f64 / rate.max(1e-9);
        eprintln!(
            "sweep: {done}/{} flights ({:.1} %), {rate:.1} flights/s, elapsed {t:.0} s, ETA {eta:.0} s",
            self.total,
            100.0 * done as f64 / self.total.max(1) as f64
        );
    }
}

/// One row per controller, its flights in sample order: what the tables
/// and the figure are made from. Refuses a set of flights in which any
/// (controller, sample) is missing or repeated.
fn aggregate(o: &SweepOptions, mut flights: Vec<(usize, SweepFlight)>) -> Result<Vec<SweepRow>> {
    let ctrls = controllers(&o.base, &o.vehicle);
    flights.sort_by_key(|(c, f)| (*c, f.sample));
    for (c, cfg) in ctrls.iter().enumerate() {
        let got: Vec<usize> = flights.iter().filter(|f| f.0 == c).map(|f| f.1.sample).collect();
        if got != (0..o.samples).collect::<Vec<_>>() {
            bail!(
                "{}: the flights are not samples 0..{} exactly once (a shard is missing or repeated)",
                label_short(cfg),
                o.samples
            );
        }
    }
    if flights.iter().any(|(c, _)| *c >= ctrls.len()) {
        bail!("a flight names a controller this sweep does not have");
    }
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
            "Robustness: position RMSE over {} vehicles (mass ±{:.0} %, inertia ±{:.0} %, drag ±{:.0} %, lag ≤ {} s, \
             kf ±{:.0} %, wind ≤ {} m/s, latency ≤ {} ms)",
            o.samples,
            100.0 * o.mass_frac,
            100.0 * o.inertia_frac,
            100.0 * o.drag_frac,
            o.lag_max_s,
            100.0 * o.kf_frac,
            o.wind_max_mps,
            1e3 * o.latency_max_s
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
         ({} s) against {} true vehicles drawn uniformly: {} (each vehicle drawn from the seed and its index alone). \
         Success: no divergence and never farther than {} m from the reference. RMSE: 3-D position error; a \
         diverged flight counts as infinite.\n",
        o.samples,
        o.seed,
        o.base.kind.name(),
        o.base.duration_s,
        o.samples,
        describe_ranges(o),
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
            progress: false,
            ..SweepOptions::defaults(
                Scenario::default_for(crate::scenario::ScenarioKind::Helix),
                PathBuf::from("/nonexistent"),
            )
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
            assert!(u.rotor_tau_s.is_some_and(|t| (0.0..=0.2).contains(&t)));
            assert!((0.9..=1.1).contains(&u.kf_scale));
            let w = u.wind_ned_mps;
            assert!((w[0] * w[0] + w[1] * w[1]).sqrt() <= 3.0 + 1e-12 && w[2] == 0.0);
            assert!((0.0..=0.005).contains(&u.latency_s));
        }
        // A vehicle depends on the seed and its index only: the first 10 of
        // a 200-vehicle sweep are those of a 10-vehicle sweep.
        let short = draw(&SweepOptions { samples: 10, ..opts(7) });
        assert_eq!(&d[..10], &short[..]);
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
