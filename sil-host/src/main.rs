//! `sil-host`: fly the flight-control core against the nonlinear plant.
//!
//! Subcommands: `open-loop` (constant inputs from hover). Closed-loop
//! flights (`fly`), controller design (`design`), MPC step inspection
//! (`mpc-step`), the framed-link server (`serve`) and the study (`report`,
//! `sweep`) build on the same plant, scenarios and metrics.

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};
use sil_host::disturbance::DisturbanceSet;
use sil_host::openloop::OpenLoop;
use sil_host::plant::{ModelKind, PlantConfig};
use sil_host::record::STATE_COLUMNS;
use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "sil-host",
    version,
    about = "Software-in-the-loop host for the quadrotor flight-control core",
    long_about = "Flies the no_std flight-control core against a nonlinear f64 plant built from the \
                  same equations (SPEC.md). Frames: earth NED (z down, altitude = -z), body FRD; \
                  angles in rad unless an option says degrees."
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Fly constant inputs from hover (thesis §3.5.3) and write the trajectory as CSV.
    OpenLoop(OpenLoopArgs),
}

/// Options shared by every command that builds a plant.
#[derive(Args, Debug, Clone)]
struct PlantArgs {
    /// Equations the plant integrates: `euler` (ZYX angles, singular at 90° pitch) or `quaternion`.
    #[arg(long, value_enum, default_value = "quaternion")]
    model: ModelKind,
    /// RK4 integration rate of the plant, Hz (each control period is cut into sub-steps at this rate).
    #[arg(long, default_value_t = 1000.0, value_name = "HZ")]
    integration_hz: f64,
    /// Turn on the first-order rotor lag (tau = 0.178 s, gain 0.936, SPEC §6).
    #[arg(long)]
    rotor_lag: bool,
    /// Disturbances acting on the plant: none, wind, mismatch or wind,mismatch (SPEC §9).
    #[arg(long, default_value = "none", value_name = "SET")]
    disturbance: DisturbanceSet,
}

impl PlantArgs {
    fn config(&self) -> Result<PlantConfig> {
        if !(self.integration_hz.is_finite() && self.integration_hz >= 1.0) {
            bail!(
                "--integration-hz must be at least 1 Hz, got {}",
                self.integration_hz
            );
        }
        let mut cfg = PlantConfig::nominal(self.model);
        cfg.integration_hz = self.integration_hz;
        cfg.rotor_lag = self.rotor_lag;
        Ok(cfg.with_disturbance(self.disturbance))
    }
}

#[derive(Args, Debug)]
struct OpenLoopArgs {
    #[command(flatten)]
    plant: PlantArgs,
    /// Constant commanded input U1,U2,U3,U4: thrust N, roll force N, pitch force N, yaw torque N·m.
    /// Goes through the mixer inverse and rotor clamping (realised inputs are in the CSV).
    #[arg(long, value_name = "U1,U2,U3,U4", value_parser = parse_list::<4>, allow_hyphen_values = true)]
    u: [f64; 4],
    /// Length of the flight, s.
    #[arg(long, default_value_t = 3.0, value_name = "SECONDS")]
    duration: f64,
    /// Start position X,Y,Z in NED metres (hovering at rest, level).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_list::<3>, allow_hyphen_values = true, default_value = "0,0,-1")]
    start: [f64; 3],
    /// Start heading, degrees.
    #[arg(
        long,
        default_value_t = 0.0,
        value_name = "DEG",
        allow_negative_numbers = true
    )]
    yaw_deg: f64,
    /// Output CSV, one row per 10 ms: t,x,y,z,vx,vy,vz,q0,q1,q2,q3,phi,theta,psi,p,q,r,u1,u2,u3,u4.
    /// Without it the last row is printed.
    #[arg(long, value_name = "PATH")]
    csv: Option<PathBuf>,
}

/// Parses `N` comma-separated finite numbers, e.g. `6.4765,0.001,0,0.01`.
fn parse_list<const N: usize>(s: &str) -> Result<[f64; N], String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != N {
        return Err(format!(
            "expected {N} comma-separated numbers, got {}",
            parts.len()
        ));
    }
    let mut out = [0.0; N];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p.parse::<f64>().map_err(|e| format!("'{p}': {e}"))?;
        if !o.is_finite() {
            return Err(format!("'{p}' is not a finite number"));
        }
    }
    Ok(out)
}

fn open_loop(a: &OpenLoopArgs) -> Result<()> {
    if !(a.duration.is_finite() && a.duration > 0.0) {
        bail!("--duration must be positive, got {}", a.duration);
    }
    let run = OpenLoop {
        plant: a.plant.config()?,
        u: nalgebra::Vector4::from(a.u),
        start_ned_m: a.start,
        start_yaw_rad: a.yaw_deg.to_radians(),
        duration_s: a.duration,
    };
    let rows = run.run();
    if let Some(path) = &a.csv {
        let f = File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut w = csv::Writer::from_writer(BufWriter::new(f));
        w.write_record(STATE_COLUMNS)?;
        for r in &rows {
            w.write_record(r.iter().map(|v| v.to_string()))?;
        }
        w.flush()?;
        eprintln!("wrote {} rows to {}", rows.len(), path.display());
    }
    if let Some(last) = rows.last() {
        for (name, v) in STATE_COLUMNS.iter().zip(last.iter()) {
            print!("{name}={v:.6} ");
        }
        println!();
    }
    Ok(())
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match &cli.command {
        Command::OpenLoop(a) => open_loop(a),
    }
}
