//! A trajectory handed to the vehicle as if a client had uploaded it
//! (`sil-host px4-hil --trajectory FILE`): the pieces of a Crazyflie
//! trajectory file, written into a trajectory memory as the Crazyflie's
//! memory port writes them, defined as trajectory 1, and started on board
//! from the hover it holds ([`fc_mavlink::vehicle::MavShared::fly_trajectory`]),
//! so that the on-board planner evaluates it and the controller previews
//! it, as over CRTP. The file is the Crazyflie's own format
//! (`uav_trajectories`, Crazyswarm's `figure8.csv`): one piece a row,
//! `duration, x^0 … x^7, y^0 … y^7, z^0 … z^7, yaw^0 … yaw^7`, in the
//! Crazyflie's world frame (x forward, y left, z up, yaw counter-clockwise),
//! a header row allowed.

use anyhow::{bail, Context, Result};
use fc_core::control::Setpoint;
use fc_loop::planner::Reference;
use fc_loop::trajectory::{
    Definition, Flight, Piece, StartOptions, TrajectoryMemory, AXIS_SIGNS, COEFFICIENTS, MAX_PIECES, PIECE_BYTES,
};
use nalgebra::Vector3;

/// The id the trajectory is defined as.
pub const TRAJECTORY_ID: u8 = 1;

/// How it starts: relative to the hover it starts from, its heading its
/// own (`autonomous_sequence_high_level.py`'s `start_trajectory(1, 1.0,
/// relative_position=True)`).
pub const START: StartOptions = StartOptions {
    time_scale: 1.0,
    reversed: false,
    relative_position: true,
    relative_yaw: false,
};

/// The pieces of `text` (the file's contents), NED (see the module).
pub fn parse(text: &str) -> Result<Vec<Piece>> {
    let mut pieces = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let numbers: Result<Vec<f32>, _> = cells.iter().map(|c| c.parse::<f32>()).collect();
        let Ok(v) = numbers else {
            if i == 0 {
                continue; // the header
            }
            bail!("line {}: not numbers", i + 1);
        };
        if v.len() != 1 + 4 * COEFFICIENTS {
            bail!(
                "line {}: {} numbers, a piece is {}",
                i + 1,
                v.len(),
                1 + 4 * COEFFICIENTS
            );
        }
        let mut poly = [[0.0f32; COEFFICIENTS]; 4];
        for (axis, row) in poly.iter_mut().enumerate() {
            for (k, c) in row.iter_mut().enumerate() {
                *c = AXIS_SIGNS[axis] * v[1 + axis * COEFFICIENTS + k];
            }
        }
        pieces.push(Piece { poly, duration_s: v[0] });
    }
    if pieces.is_empty() {
        bail!("no piece");
    }
    Ok(pieces)
}

/// The trajectory memory holding `pieces` from byte 0, defined as
/// [`TRAJECTORY_ID`] (the memory's own checks: finite, positive durations,
/// within its size), and the trajectory's duration, s. The memory lives as
/// long as the process (the vehicle flies from it).
pub fn memory(pieces: &[Piece]) -> Result<(&'static TrajectoryMemory, f32)> {
    if pieces.len() > MAX_PIECES {
        bail!("{} pieces: the trajectory memory holds {MAX_PIECES}", pieces.len());
    }
    let mut m = Box::new(TrajectoryMemory::new());
    for (i, p) in pieces.iter().enumerate() {
        m.write((i * PIECE_BYTES) as u32, &p.to_bytes())
            .map_err(|e| anyhow::anyhow!("piece {i}: {e}"))?;
    }
    let def = Definition::new(0, pieces.len() as u8).map_err(|e| anyhow::anyhow!("{e}"))?;
    m.define(TRAJECTORY_ID, def).map_err(|e| anyhow::anyhow!("{e}"))?;
    let duration_s = m.check(&def).map_err(|e| anyhow::anyhow!("{e}"))?;
    Ok((Box::leak(m), duration_s))
}

/// Reads the file at `path` into a memory ([`parse`], [`memory`]).
pub fn load(path: &std::path::Path) -> Result<(&'static TrajectoryMemory, f32)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let pieces = parse(&text).with_context(|| format!("{}", path.display()))?;
    memory(&pieces).with_context(|| format!("{}", path.display()))
}

/// The trajectory as the vehicle flies it, for the host's own trace and
/// error: started at `from_s` (the mission's clock, µs exact) from a hover
/// at `hover_ned_m`, heading north, as the vehicle starts it.
#[derive(Debug, Clone, Copy)]
pub struct Flown {
    /// The memory it is evaluated from.
    pub memory: &'static TrajectoryMemory,
    /// The flight, on the mission's clock (µs since the first sample).
    pub flight: Flight,
    /// Its duration, s.
    pub duration_s: f32,
    /// When it starts, s after the first sample.
    pub from_s: f64,
    /// The hover it starts from (heading north), NED about home, m.
    pub hover_ned_m: [f64; 3],
}

impl Flown {
    /// The flight of `memory`'s trajectory from `from_s`, from a hover at `hover_ned_m`.
    pub fn new(memory: &'static TrajectoryMemory, duration_s: f32, from_s: f64, hover_ned_m: [f64; 3]) -> Result<Self> {
        let hover = Reference::at_rest(Vector3::from(hover_ned_m).cast(), 0.0);
        let flight = Flight::start(memory, TRAJECTORY_ID, (from_s * 1e6).round() as u64, START, &hover)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok(Self {
            memory,
            flight,
            duration_s,
            from_s,
            hover_ned_m,
        })
    }

    /// Its set-point at `t` s on the mission's clock: the hover before it
    /// starts, then the trajectory's point with its jerk.
    pub fn setpoint_at(&self, t: f64) -> Setpoint<f32> {
        if t < self.from_s {
            return Setpoint::hold(Vector3::from(self.hover_ned_m).cast(), 0.0);
        }
        let s = self
            .flight
            .sample(self.memory.bytes(), (t.max(0.0) * 1e6).round() as u64);
        let mut sp = s.reference.setpoint();
        sp.jerk_ned_mps3 = s.jerk_ned_mps3;
        sp
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_crazyflie_file_reads_in_its_frame_and_flies_from_the_hover() {
        // x = t (forward), y = 2t (left), z = 0.5 t² (up), yaw = 0.1 t, over 2 s.
        let mut row = vec![0.0f32; 33];
        row[0] = 2.0;
        row[2] = 1.0;
        row[10] = 2.0;
        row[19] = 0.5;
        row[26] = 0.1;
        let line = row.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",");
        let text = format!("Duration,x^0,...\n{line}\n");
        let pieces = parse(&text).unwrap();
        let (m, duration_s) = memory(&pieces).unwrap();
        assert_eq!(duration_s, 2.0);
        let f = Flown::new(m, duration_s, 3.0, [0.0, 0.0, -1.0]).unwrap();
        let sp = f.setpoint_at(4.0);
        // NED: north = x, east = −y, down = −z; heading −yaw.
        assert!((sp.pos_ned_m - Vector3::new(1.0, -2.0, -1.5)).amax() < 1e-6, "{sp:?}");
        assert!((sp.vel_ned_mps - Vector3::new(1.0, -2.0, -1.0)).amax() < 1e-6, "{sp:?}");
        assert!((sp.acc_ned_mps2 - Vector3::new(0.0, 0.0, -1.0)).amax() < 1e-6, "{sp:?}");
        assert!(
            (sp.yaw_rad + 0.1).abs() < 1e-6 && (sp.yaw_rate_radps + 0.1).abs() < 1e-6,
            "{sp:?}"
        );
        assert_eq!(
            f.setpoint_at(1.0).pos_ned_m,
            Vector3::new(0.0, 0.0, -1.0),
            "the hover before"
        );
        // Refused by name: a short row, NaN, a zero duration.
        assert!(format!("{:#}", parse("1,2,3").unwrap_err()).contains("3 numbers"));
        let mut bad = row.clone();
        bad[5] = f32::NAN;
        let nan = bad.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",");
        assert!(format!("{:#}", memory(&parse(&nan).unwrap()).unwrap_err()).contains("piece"));
        let mut zero = row;
        zero[0] = 0.0;
        let zero = zero.iter().map(|v| v.to_string()).collect::<Vec<_>>().join(",");
        assert!(memory(&parse(&zero).unwrap()).is_err());
    }
}
