//! Figures of the report, in the thesis' manner: one figure per file, each
//! written as SVG and PNG (plotters, with an embedded DejaVu Sans so no
//! system font is needed). Axes are labelled with units; every figure has a
//! legend where it has more than one series.

use anyhow::{anyhow, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// One line of a panel.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// `(x, y)` points.
    pub points: Vec<(f64, f64)>,
    /// Colour index into the report palette (`None`: black, the reference).
    pub color: Option<usize>,
    /// Dashed (references and bounds).
    pub dashed: bool,
}

impl Series {
    /// A solid line in palette colour `color`.
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>, color: usize) -> Self {
        Self {
            name: name.into(),
            points,
            color: Some(color),
            dashed: false,
        }
    }

    /// A dashed black line (a reference).
    pub fn reference(name: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Self {
            name: name.into(),
            points,
            color: None,
            dashed: true,
        }
    }
}

/// One panel (sub-plot) of a figure.
#[derive(Debug, Clone)]
pub struct Panel {
    /// x-axis label with unit.
    pub x_label: String,
    /// y-axis label with unit.
    pub y_label: String,
    /// Lines.
    pub series: Vec<Series>,
    /// Horizontal dashed red lines `(y, label)`: input bounds.
    pub bounds: Vec<(f64, String)>,
    /// Same scale on both axes (paths seen from above).
    pub equal_axes: bool,
}

impl Panel {
    /// A panel with labels and lines.
    pub fn new(x_label: impl Into<String>, y_label: impl Into<String>, series: Vec<Series>) -> Self {
        Self {
            x_label: x_label.into(),
            y_label: y_label.into(),
            series,
            bounds: Vec::new(),
            equal_axes: false,
        }
    }
}

/// A figure's content.
#[derive(Debug, Clone)]
pub enum Plot {
    /// Panels stacked vertically, sharing nothing but the figure.
    Panels(Vec<Panel>),
    /// Grouped bars: categories, groups `(name, value per category)`, y label.
    Bars {
        /// Category labels along x.
        categories: Vec<String>,
        /// One bar per group in each category.
        groups: Vec<(String, Vec<f64>)>,
        /// y-axis label with unit.
        y_label: String,
    },
    /// 3-D paths `(x, y, altitude)` with axis labels.
    Path3d {
        /// Lines (points as x north m, y east m, altitude m).
        series: Vec<Path3>,
        /// Axis labels.
        labels: [String; 3],
    },
}

/// A figure: file stem, title and content.
#[derive(Debug, Clone)]
pub struct Figure {
    /// File name without extension (`.svg` and `.png` are written).
    pub stem: String,
    /// Title drawn on the figure and used as the caption.
    pub title: String,
    /// What is drawn.
    pub plot: Plot,
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(23, 190, 207),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
];

/// Draws a chart's legend box at a corner (2-D and 3-D charts alike).
macro_rules! legend {
    ($chart:expr, $pos:ident) => {
        $chart
            .configure_series_labels()
            .position(SeriesLabelPosition::$pos)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font(("sans-serif", 13))
            .draw()
            .map_err(err)?
    };
}

fn color(c: Option<usize>) -> RGBColor {
    c.map_or(BLACK, |i| PALETTE[i % PALETTE.len()])
}

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let font: &'static [u8] = include_bytes!("../assets/DejaVuSans.ttf");
        // A bad embedded font would be a build defect; text then falls back to nothing.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, font);
    });
}

/// Size of one panel and of the figure.
fn size(plot: &Plot) -> (u32, u32) {
    match plot {
        Plot::Panels(p) if p.len() == 1 && p[0].equal_axes => (760, 760),
        Plot::Panels(p) => (960, 120 + 260 * p.len().max(1) as u32),
        Plot::Bars { .. } => (960, 520),
        Plot::Path3d { .. } => (900, 760),
    }
}

/// Writes `dir/stem.svg` and `dir/stem.png`.
pub fn write(dir: &Path, fig: &Figure) -> Result<()> {
    register_font();
    let (w, h) = size(&fig.plot);
    let svg = dir.join(format!("{}.svg", fig.stem));
    let png = dir.join(format!("{}.png", fig.stem));
    {
        let root = SVGBackend::new(&svg, (w, h)).into_drawing_area();
        draw(&root, fig)?;
        root.present().map_err(|e| anyhow!("{}: {e:?}", svg.display()))?;
    }
    {
        let root = BitMapBackend::new(&png, (w, h)).into_drawing_area();
        draw(&root, fig)?;
        root.present().map_err(|e| anyhow!("{}: {e:?}", png.display()))?;
    }
    Ok(())
}

fn err<E: std::fmt::Debug>(e: E) -> anyhow::Error {
    anyhow!("drawing: {e:?}")
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3 * (1.0 + hi.abs().max(lo.abs())));
    (lo - pad, hi + pad)
}

fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, fig: &Figure) -> Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(&fig.title, ("sans-serif", 22).into_font()).map_err(err)?;
    match &fig.plot {
        Plot::Panels(panels) => {
            let areas = root.split_evenly((panels.len().max(1), 1));
            for (area, p) in areas.iter().zip(panels) {
                draw_panel(area, p)?;
            }
        }
        Plot::Bars {
            categories,
            groups,
            y_label,
        } => draw_bars(&root, categories, groups, y_label)?,
        Plot::Path3d { series, labels } => draw_3d(&root, series, labels)?,
    }
    Ok(())
}

fn draw_panel<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, p: &Panel) -> Result<()> {
    let (mut x0, mut x1) = range(p.series.iter().flat_map(|s| s.points.iter().map(|q| q.0)));
    let (mut y0, mut y1) = range(
        p.series
            .iter()
            .flat_map(|s| s.points.iter().map(|q| q.1))
            .chain(p.bounds.iter().map(|b| b.0)),
    );
    if p.equal_axes {
        let span = (x1 - x0).max(y1 - y0) / 2.0;
        let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
        (x0, x1, y0, y1) = (cx - span, cx + span, cy - span, cy + span);
    }
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .light_line_style(WHITE)
        .draw()
        .map_err(err)?;
    for (y, label) in &p.bounds {
        let style = ShapeStyle::from(&RED.mix(0.7)).stroke_width(1);
        chart
            .draw_series(DashedLineSeries::new(vec![(x0, *y), (x1, *y)], 6, 4, style))
            .map_err(err)?
            .label(label.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    for s in &p.series {
        let c = color(s.color);
        let style = ShapeStyle::from(&c).stroke_width(if s.dashed { 1 } else { 2 });
        let anno = if s.dashed {
            chart
                .draw_series(DashedLineSeries::new(s.points.iter().copied(), 8, 5, style))
                .map_err(err)?
        } else {
            chart
                .draw_series(LineSeries::new(s.points.iter().copied(), style))
                .map_err(err)?
        };
        // An unnamed series (the second edge of a band) has no legend entry.
        if !s.name.is_empty() {
            anno.label(s.name.as_str())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
        }
    }
    if p.series.len() + p.bounds.len() > 1 {
        legend!(chart, UpperRight);
    }
    Ok(())
}

fn draw_bars<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    categories: &[String],
    groups: &[(String, Vec<f64>)],
    y_label: &str,
) -> Result<()> {
    let n = categories.len().max(1) as f64;
    let (_, top) = range(groups.iter().flat_map(|g| g.1.iter().copied()).chain([0.0]));
    let mut chart = ChartBuilder::on(area)
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(70)
        .build_cartesian_2d(-0.5..n - 0.5, 0.0..top)
        .map_err(err)?;
    let cats = categories.to_vec();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(categories.len())
        .x_label_formatter(&|x| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < cats.len() {
                cats[i as usize].clone()
            } else {
                String::new()
            }
        })
        .y_desc(y_label)
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 15))
        .draw()
        .map_err(err)?;
    let width = 0.8 / groups.len().max(1) as f64;
    for (gi, (name, values)) in groups.iter().enumerate() {
        let c = PALETTE[gi % PALETTE.len()];
        chart
            .draw_series(values.iter().enumerate().map(|(i, v)| {
                let x = i as f64 - 0.4 + gi as f64 * width;
                Rectangle::new([(x, 0.0), (x + width * 0.95, *v)], c.filled())
            }))
            .map_err(err)?
            .label(name.as_str())
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
    }
    legend!(chart, UpperLeft);
    Ok(())
}

/// A named 3-D line `(name, points, colour)`.
pub type Path3 = (String, Vec<(f64, f64, f64)>, Option<usize>);

fn draw_3d<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, series: &[Path3], labels: &[String; 3]) -> Result<()> {
    let all = || series.iter().flat_map(|s| s.1.iter());
    let (x0, x1) = range(all().map(|p| p.0));
    let (y0, y1) = range(all().map(|p| p.1));
    let (z0, z1) = range(all().map(|p| p.2));
    // plotters' 3-D y axis is the vertical one: (north, altitude, east).
    let mut chart = ChartBuilder::on(area)
        .margin(20)
        .build_cartesian_3d(x0..x1, z0..z1, y0..y1)
        .map_err(err)?;
    chart.with_projection(|mut p| {
        p.pitch = 0.45;
        p.yaw = 0.6;
        p.scale = 0.75;
        p.into_matrix()
    });
    chart
        .configure_axes()
        .label_style(("sans-serif", 13))
        .light_grid_style(RGBColor(225, 225, 225))
        .max_light_lines(4)
        .draw()
        .map_err(err)?;
    for (name, pts, c) in series {
        let col = color(*c);
        let style = ShapeStyle::from(&col).stroke_width(if c.is_some() { 2 } else { 1 });
        chart
            .draw_series(LineSeries::new(pts.iter().map(|p| (p.0, p.2, p.1)), style))
            .map_err(err)?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
    }
    legend!(chart, UpperRight);
    // Axis names (plotters' 3-D axes carry numbers only).
    area.draw(&Text::new(
        format!("axes: {} (front), {} (right), {} (up)", labels[0], labels[1], labels[2]),
        (20, 40),
        ("sans-serif", 14).into_font(),
    ))
    .map_err(err)?;
    Ok(())
}

/// Keeps at most `n` evenly spaced points (plots need no more).
pub fn decimate<T: Copy>(v: &[T], n: usize) -> Vec<T> {
    if v.len() <= n || n < 2 {
        return v.to_vec();
    }
    let step = (v.len() - 1) as f64 / (n - 1) as f64;
    (0..n)
        .map(|i| v[((i as f64 * step).round() as usize).min(v.len() - 1)])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_svg_and_png_with_text() {
        let dir = std::env::temp_dir().join(format!("sil-fig-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let pts: Vec<(f64, f64)> = (0..100).map(|i| (i as f64 * 0.1, (i as f64 * 0.1).sin())).collect();
        let mut panel = Panel::new("t (s)", "x (m)", vec![Series::line("sin", pts.clone(), 0)]);
        panel.series.push(Series::reference("reference", pts));
        panel.bounds.push((1.0, "bound".into()));
        let fig = Figure {
            stem: "t".into(),
            title: "A test figure".into(),
            plot: Plot::Panels(vec![panel]),
        };
        write(&dir, &fig).unwrap();
        let svg = std::fs::read_to_string(dir.join("t.svg")).unwrap();
        assert!(svg.contains("A test figure") && svg.contains("t (s)") && svg.contains("reference"));
        let png = std::fs::read(dir.join("t.png")).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn decimate_keeps_ends() {
        let v: Vec<usize> = (0..1001).collect();
        let d = decimate(&v, 11);
        assert_eq!(d.len(), 11);
        assert_eq!((d[0], d[10], d[5]), (0, 1000, 500));
    }
}
