//! CSV recording of flights: one row per 10 ms of simulated time, columns
//! `t,x,y,z,vx,vy,vz,q0,q1,q2,q3,phi,theta,psi,p,q,r,u1,u2,u3,u4` (u = inputs
//! realised by the plant), plus `x_ref,y_ref,z_ref,psi_ref` for closed-loop flights.

use crate::plant::Plant;
use crate::scenario::Reference;
use firmware::quat_to_euler;
use std::io::Write;

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

/// Writes rows to a CSV file (numbers in shortest round-trip form).
pub struct CsvRecorder<W: Write> {
    w: csv::Writer<W>,
    with_reference: bool,
}

impl<W: Write> CsvRecorder<W> {
    /// Starts a CSV with the header; `with_reference` adds the reference columns.
    pub fn new(out: W, with_reference: bool) -> anyhow::Result<Self> {
        let mut w = csv::Writer::from_writer(out);
        let mut header: Vec<&str> = STATE_COLUMNS.to_vec();
        if with_reference {
            header.extend_from_slice(&REFERENCE_COLUMNS);
        }
        w.write_record(&header)?;
        Ok(Self { w, with_reference })
    }

    /// Appends one row for the plant's current state (and reference).
    pub fn row(&mut self, plant: &Plant, reference: Option<&Reference>) -> anyhow::Result<()> {
        let mut fields: Vec<String> = state_row(plant).iter().map(|v| v.to_string()).collect();
        if self.with_reference {
            let r = reference.ok_or_else(|| anyhow::anyhow!("closed-loop row without a reference"))?;
            fields.extend([r.pos[0], r.pos[1], r.pos[2], r.yaw].iter().map(|v| v.to_string()));
        }
        self.w.write_record(&fields)?;
        Ok(())
    }

    /// Flushes the file.
    pub fn finish(mut self) -> anyhow::Result<()> {
        self.w.flush()?;
        Ok(())
    }
}
