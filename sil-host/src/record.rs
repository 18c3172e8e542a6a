//! CSV recording of flights: one row per 10 ms of simulated time, columns
//! `t,x,y,z,vx,vy,vz,q0,q1,q2,q3,phi,theta,psi,p,q,r,u1,u2,u3,u4` (u = inputs
//! realised by the plant), plus `x_ref,y_ref,z_ref,psi_ref` for closed-loop flights.

use crate::plant::Plant;
use anyhow::Context;
use fc_core::quat_to_euler;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

/// Recording interval, s.
pub const RECORD_DT_S: f64 = 0.01;

/// Column names of the state part of a row.
pub const STATE_COLUMNS: [&str; 21] = [
    "t", "x", "y", "z", "vx", "vy", "vz", "q0", "q1", "q2", "q3", "phi", "theta", "psi", "p", "q", "r", "u1", "u2",
    "u3", "u4",
];
/// Extra columns of closed-loop flights.
pub const REFERENCE_COLUMNS: [&str; 4] = ["x_ref", "y_ref", "z_ref", "psi_ref"];

/// One row's state part from the plant: time, quaternion state, Euler angles,
/// realised inputs.
pub fn state_row(plant: &Plant) -> [f64; 21] {
    let x = plant.quat_state();
    let e = match plant.body() {
        crate::plant::BodyState::Euler(xe) => nalgebra::Vector3::new(xe[6], xe[7], xe[8]),
        crate::plant::BodyState::Quat(_) => quat_to_euler(&x.fixed_rows::<4>(6).into_owned()),
    };
    let u = plant.realised_inputs();
    let mut r = [0.0; 21];
    r[0] = plant.time();
    r[1..11].copy_from_slice(&x.as_slice()[0..10]);
    r[11..14].copy_from_slice(e.as_slice());
    r[14..17].copy_from_slice(&x.as_slice()[10..13]);
    r[17..21].copy_from_slice(u.as_slice());
    r
}

/// Where a flight's record rows go as they are produced, one every
/// [`RECORD_DT_S`]: a file, memory, or nowhere. A flight written to a file
/// never holds its trace in memory.
pub trait RowSink {
    /// Takes one row: the state part and, for closed-loop flights, the
    /// reference `[x, y, z, ψ]` at the same time.
    fn push(&mut self, row: &[f64; 21], reference: Option<&[f64; 4]>) -> anyhow::Result<()>;

    /// Takes the on-board estimate of a sensor flight at time `t` (s), at
    /// the rows' rate; sinks that do not record it ignore it.
    fn estimate(&mut self, _t: f64, _nav: &crate::endpoint::NavReport) -> anyhow::Result<()> {
        Ok(())
    }

    /// Takes a line of the flight controller's log at time `t` (s);
    /// sinks that do not record it ignore it.
    fn log(&mut self, _t: f64, _text: &str) -> anyhow::Result<()> {
        Ok(())
    }
}

/// A sink that drops every row (a flight whose metrics are all that is wanted).
#[derive(Debug, Default, Clone, Copy)]
pub struct Discard;

impl RowSink for Discard {
    fn push(&mut self, _: &[f64; 21], _: Option<&[f64; 4]>) -> anyhow::Result<()> {
        Ok(())
    }
}

/// Rows kept in memory (state part only).
impl RowSink for Vec<[f64; 21]> {
    fn push(&mut self, row: &[f64; 21], _: Option<&[f64; 4]>) -> anyhow::Result<()> {
        Vec::push(self, *row);
        Ok(())
    }
}

/// Rows streamed to a CSV file as they come (numbers in shortest
/// round-trip form): the state columns, plus the reference columns for
/// closed-loop flights. Call [`CsvSink::finish`] to flush and learn the count.
pub struct CsvSink {
    w: csv::Writer<BufWriter<File>>,
    path: std::path::PathBuf,
    with_reference: bool,
    rows: usize,
}

impl CsvSink {
    /// Creates `path` and writes the header (`with_reference` adds
    /// [`REFERENCE_COLUMNS`]).
    pub fn create(path: &Path, with_reference: bool) -> anyhow::Result<Self> {
        let f = File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = csv::Writer::from_writer(BufWriter::new(f));
        let mut header: Vec<&str> = STATE_COLUMNS.to_vec();
        if with_reference {
            header.extend_from_slice(&REFERENCE_COLUMNS);
        }
        w.write_record(&header)
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(CsvSink {
            w,
            path: path.to_path_buf(),
            with_reference,
            rows: 0,
        })
    }

    /// Flushes the file; returns the number of rows written.
    pub fn finish(mut self) -> anyhow::Result<usize> {
        self.w
            .flush()
            .with_context(|| format!("writing {}", self.path.display()))?;
        Ok(self.rows)
    }
}

impl RowSink for CsvSink {
    fn push(&mut self, row: &[f64; 21], reference: Option<&[f64; 4]>) -> anyhow::Result<()> {
        let r: &[f64] = match (self.with_reference, reference) {
            (true, Some(r)) => r.as_slice(),
            (true, None) => anyhow::bail!("{}: a row without its reference", self.path.display()),
            (false, _) => &[],
        };
        self.w
            .write_record(row.iter().chain(r).map(|v| v.to_string()))
            .with_context(|| format!("writing {}", self.path.display()))?;
        self.rows += 1;
        Ok(())
    }
}

/// Writes stored rows as CSV to `path` (see [`CsvSink`]), with the reference
/// columns when `reference` gives one `[x, y, z, ψ]` per row.
pub fn write_csv(path: &Path, rows: &[[f64; 21]], reference: Option<&[[f64; 4]]>) -> anyhow::Result<()> {
    let mut sink = CsvSink::create(path, reference.is_some())?;
    for (i, row) in rows.iter().enumerate() {
        sink.push(row, reference.and_then(|refs| refs.get(i)))?;
    }
    sink.finish()?;
    Ok(())
}

/// Makes sure `dir` can take a command's output *before* the work starts:
/// creates it if missing; refuses a path that exists and is not a directory,
/// or a directory this process cannot write into (checked by creating and
/// removing a probe file), with a message naming the path.
pub fn prepare_output_dir(dir: &Path) -> anyhow::Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!("output directory {} exists and is not a directory", dir.display());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating output directory {}", dir.display()))?;
    let probe = dir.join(".sil-host-write-probe");
    File::create(&probe).with_context(|| format!("output directory {} is not writable", dir.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}
