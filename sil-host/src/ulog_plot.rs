//! The report's position figures drawn from a ULog: any log with PX4's
//! `vehicle_local_position` (or its ground truth) and
//! `vehicle_local_position_setpoint`, this project's or PX4's own. The log
//! is read with `yule_log`, a ULog parser this project did not write.

use crate::figures::{Figure, Panel, Plot, Series};
use anyhow::{bail, Context, Result};
use std::fs::File;
use std::io::BufReader;
use std::path::Path;
use yule_log::builder::ULogParserBuilder;
use yule_log::model::inst::FieldValue;
use yule_log::model::msg::UlogMessage;

/// Positions read from a log: NED m against s from the log's start.
#[derive(Debug, Default, Clone)]
pub struct Tracks {
    /// The topic the flown position came from: the ground truth when the
    /// log has it, the estimate otherwise.
    pub source: String,
    /// `(t s, [x, y, z] m)` of the flown position.
    pub flown: Vec<(f64, [f64; 3])>,
    /// `(t s, [x, y, z] m)` of the set-point.
    pub setpoint: Vec<(f64, [f64; 3])>,
}

fn xyz(fields: &[yule_log::model::inst::Field]) -> Option<[f64; 3]> {
    let mut out = [f64::NAN; 3];
    for f in fields {
        let i = match &*f.name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => continue,
        };
        out[i] = match f.value {
            FieldValue::ScalarF32(v) => f64::from(v),
            FieldValue::ScalarF64(v) => v,
            _ => return None,
        };
    }
    Some(out)
}

/// Reads the flown position and the set-point from the ULog at `path`.
pub fn read_tracks(path: &Path) -> Result<Tracks> {
    let f = File::open(path).with_context(|| format!("opening {}", path.display()))?;
    let parser = ULogParserBuilder::new(BufReader::new(f))
        .include_timestamp(true)
        .build()
        .map_err(|e| anyhow::anyhow!("{}: not a ULog: {e}", path.display()))?;
    let (mut truth, mut estimate, mut setpoint) = (Vec::new(), Vec::new(), Vec::new());
    for msg in parser {
        let msg = msg.map_err(|e| anyhow::anyhow!("{}: not a ULog, or a damaged one: {e}", path.display()))?;
        let UlogMessage::LoggedData(d) = msg else {
            continue;
        };
        let into = match &*d.data.name {
            "vehicle_local_position_groundtruth" => &mut truth,
            "vehicle_local_position" => &mut estimate,
            "vehicle_local_position_setpoint" => &mut setpoint,
            _ => continue,
        };
        if let Some(p) = xyz(&d.data.fields) {
            into.push((d.timestamp as f64 * 1e-6, p));
        }
    }
    let (source, flown) = if truth.is_empty() {
        ("vehicle_local_position", estimate)
    } else {
        ("vehicle_local_position_groundtruth", truth)
    };
    if flown.is_empty() {
        bail!(
            "{}: no vehicle_local_position or vehicle_local_position_groundtruth samples to draw",
            path.display()
        );
    }
    Ok(Tracks {
        source: source.into(),
        flown,
        setpoint,
    })
}

/// The report's two position figures for `tracks`: position against time
/// (one panel per axis, the set-point dashed) and the path seen from above.
pub fn figures(stem: &str, tracks: &Tracks) -> [Figure; 2] {
    let axis = |which: usize, of: &[(f64, [f64; 3])]| -> Vec<(f64, f64)> {
        of.iter()
            .filter(|(_, p)| p[which].is_finite())
            .map(|(t, p)| (*t, p[which]))
            .collect()
    };
    let panels = ["x (north) m", "y (east) m", "z (down) m"]
        .iter()
        .enumerate()
        .map(|(i, label)| {
            let mut series = vec![Series::line("flown", axis(i, &tracks.flown), 0)];
            if !tracks.setpoint.is_empty() {
                series.push(Series::reference("set-point", axis(i, &tracks.setpoint)));
            }
            Panel::new("t s", *label, series)
        })
        .collect();
    let top = |of: &[(f64, [f64; 3])]| -> Vec<(f64, f64)> {
        of.iter()
            .filter(|(_, p)| p[0].is_finite() && p[1].is_finite())
            .map(|(_, p)| (p[1], p[0]))
            .collect()
    };
    let mut path = Panel::new(
        "y (east) m",
        "x (north) m",
        vec![Series::line("flown", top(&tracks.flown), 0)],
    );
    if !tracks.setpoint.is_empty() {
        path.series.push(Series::reference("set-point", top(&tracks.setpoint)));
    }
    path.equal_axes = true;
    [
        Figure {
            stem: format!("{stem}_position"),
            title: format!("{stem}: position against time ({})", tracks.source),
            plot: Plot::Panels(panels),
        },
        Figure {
            stem: format!("{stem}_path_top"),
            title: format!("{stem}: path seen from above"),
            plot: Plot::Panels(vec![path]),
        },
    ]
}
