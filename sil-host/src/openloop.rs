//! Open-loop flights: constant inputs from hover (thesis §3.5.3).

use crate::plant::{Plant, PlantConfig};
use crate::record::{state_row, RowSink, RECORD_DT_S};
use fc_core::{hover_quat_state, Input};
use nalgebra::Vector3;

/// An open-loop run: constant commanded input from a hover state.
#[derive(Debug, Clone, Copy)]
pub struct OpenLoop {
    /// The plant.
    pub plant: PlantConfig,
    /// Commanded input, held for the whole run.
    pub u: Input<f64>,
    /// Start position, NED, m.
    pub start_ned_m: [f64; 3],
    /// Start heading, rad.
    pub start_yaw_rad: f64,
    /// Length, s.
    pub duration_s: f64,
}

impl OpenLoop {
    /// Flies the run and returns one state row (see [`crate::record::STATE_COLUMNS`])
    /// per 10 ms, including t = 0 and the end.
    pub fn run(&self) -> Vec<[f64; 21]> {
        let mut rows = Vec::with_capacity((self.duration_s / RECORD_DT_S).round() as usize + 1);
        // A Vec takes every row; it cannot fail.
        let _ = self.run_into(&mut rows);
        rows
    }

    /// Flies the run, handing each row to `sink` as it is produced (memory
    /// constant in the run's length); stops at the sink's first error.
    /// Returns the last row (the state at the end).
    pub fn run_into(&self, sink: &mut dyn RowSink) -> anyhow::Result<[f64; 21]> {
        let x0 = hover_quat_state(&Vector3::from(self.start_ned_m), self.start_yaw_rad);
        let mut plant = Plant::new(self.plant, &x0);
        let steps = (self.duration_s / RECORD_DT_S).round() as usize;
        // Row 0 shows the input that acts from t = 0.
        let mut first = state_row(&plant);
        first[17..21].copy_from_slice(plant.inputs_realised_for(&self.u).as_slice());
        sink.push(&first, None)?;
        let mut last = first;
        for _ in 0..steps {
            plant.step(&self.u, RECORD_DT_S);
            last = state_row(&plant);
            sink.push(&last, None)?;
        }
        Ok(last)
    }
}
