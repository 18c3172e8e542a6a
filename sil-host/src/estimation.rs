//! How good the on-board estimate was: its errors against the true state
//! (and the sensors' true biases), the σ it claimed, and their ratio, the
//! normalised estimation error squared (NEES, `eᵀP⁻¹e`: χ² with 15 degrees
//! of freedom for a consistent filter).

use crate::endpoint::NavReport;
use crate::sensors::attitude_error;
use fc_core::estimate::{EskfCounters, ERR};
use fc_core::QuatState;
use fc_loop::nav::NavMode;
use nalgebra::{SMatrix, SVector, Vector3, Vector4};
use serde::Serialize;

/// One estimation sample: the error `truth ⊖ estimate` `[δp δv δθ δb_g δb_a]`
/// (m, m/s, rad, rad/s, m/s²), the claimed 1σ of each, and the NEES.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EstSample {
    /// Time, s.
    pub t: f64,
    /// Error per state.
    pub err: [f64; ERR],
    /// The filter's 1σ per state.
    pub sigma: [f64; ERR],
    /// `eᵀP⁻¹e` (NaN if P was not positive definite).
    pub nees: f64,
    /// The same for each block alone (its marginal covariance): position,
    /// velocity, attitude, gyro bias, accelerometer bias (χ², 3 dof each).
    pub nees_blocks: [f64; 5],
}

/// What a sensor flight's estimator did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EstimationResult {
    /// IMU steps with an estimate.
    pub samples: usize,
    /// IMU steps spent aligning.
    pub aligning_steps: usize,
    /// IMU steps in the estimator's failsafe.
    pub failsafe_steps: usize,
    /// Failsafe episodes.
    pub failsafe_entries: u32,
    /// RMS of the attitude error angle, degrees.
    pub rms_att_deg: f64,
    /// RMS of the position error (3-D), m.
    pub rms_pos_m: f64,
    /// RMS of the velocity error (3-D), m/s.
    pub rms_vel_mps: f64,
    /// Largest position error (3-D), m.
    pub max_pos_m: f64,
    /// Mean NEES (15 for a consistent filter); NaN without a covariance (remote targets).
    pub nees_mean: f64,
    /// Mean NEES of each block: position, velocity, attitude, gyro bias,
    /// accelerometer bias (3 for a consistent filter).
    pub nees_blocks_mean: [f64; 5],
    /// Samples and times, kept only for kept recordings.
    #[serde(skip)]
    pub trace: Vec<EstSample>,
    /// What the estimator refused or repaired.
    #[serde(skip)]
    pub counters: EskfCounters,
}

/// Accumulates [`EstimationResult`] step by step.
#[derive(Debug, Clone, Default)]
pub struct EstimationAccumulator {
    n: usize,
    aligning: usize,
    failsafe: usize,
    entries: u32,
    sum_att: f64,
    sum_pos: f64,
    sum_vel: f64,
    max_pos: f64,
    sum_nees: f64,
    sum_blocks: [f64; 5],
    n_nees: usize,
    last: Option<EstSample>,
    counters: EskfCounters,
}

/// The error of a report against the truth, or `None` while aligning.
pub fn sample(
    t: f64,
    truth: &QuatState<f64>,
    true_biases: &(Vector3<f64>, Vector3<f64>),
    r: &NavReport,
) -> Option<EstSample> {
    let e = r.estimate?;
    let mut err = SVector::<f64, ERR>::zeros();
    for i in 0..3 {
        err[i] = truth[i] - f64::from(e.pos_ned_m[i]);
        err[3 + i] = truth[3 + i] - f64::from(e.vel_ned_mps[i]);
        err[9 + i] = true_biases.0[i] - f64::from(r.biases.0[i]);
        err[12 + i] = true_biases.1[i] - f64::from(r.biases.1[i]);
    }
    let qt = Vector4::new(truth[6], truth[7], truth[8], truth[9]);
    let dth = attitude_error(&qt, &e.att.cast());
    err.fixed_rows_mut::<3>(6).copy_from(&dth);
    let sigma = SVector::<f64, ERR>::from(r.sigmas.map(f64::from));
    let mut nees = f64::NAN;
    let mut nees_blocks = [f64::NAN; 5];
    if let Some(cov) = r.covariance {
        let p: SMatrix<f64, ERR, ERR> = cov.cast();
        if let Some(c) = p.cholesky() {
            nees = err.dot(&c.solve(&err));
        }
        for (b, out) in nees_blocks.iter_mut().enumerate() {
            let pb = p.fixed_view::<3, 3>(3 * b, 3 * b).into_owned();
            let eb = err.fixed_rows::<3>(3 * b).into_owned();
            if let Some(c) = pb.cholesky() {
                *out = eb.dot(&c.solve(&eb));
            }
        }
    }
    Some(EstSample {
        t,
        err: err.into(),
        sigma: sigma.into(),
        nees,
        nees_blocks,
    })
}

impl EstimationAccumulator {
    /// Adds one IMU step's report (with the truth at that time).
    pub fn push(&mut self, t: f64, truth: &QuatState<f64>, true_biases: &(Vector3<f64>, Vector3<f64>), r: &NavReport) {
        self.counters = r.counters;
        self.entries = r.failsafe_entries;
        match r.mode {
            NavMode::Aligning => self.aligning += 1,
            NavMode::Failsafe => self.failsafe += 1,
            NavMode::Navigating => {}
        }
        let Some(s) = sample(t, truth, true_biases, r) else {
            return;
        };
        let norm = |a: usize| (s.err[a].powi(2) + s.err[a + 1].powi(2) + s.err[a + 2].powi(2)).sqrt();
        let (pos, vel, att) = (norm(0), norm(3), norm(6));
        self.n += 1;
        self.sum_pos += pos * pos;
        self.sum_vel += vel * vel;
        self.sum_att += att * att;
        self.max_pos = self.max_pos.max(pos);
        if s.nees.is_finite() && s.nees_blocks.iter().all(|v| v.is_finite()) {
            self.sum_nees += s.nees;
            for (acc, v) in self.sum_blocks.iter_mut().zip(s.nees_blocks) {
                *acc += v;
            }
            self.n_nees += 1;
        }
        self.last = Some(s);
    }

    /// The latest sample (for recording at the record rate).
    pub fn last(&self) -> Option<EstSample> {
        self.last
    }

    /// The result so far, with `trace` as the kept samples.
    pub fn result(&self, trace: Vec<EstSample>) -> EstimationResult {
        let n = self.n.max(1) as f64;
        EstimationResult {
            samples: self.n,
            aligning_steps: self.aligning,
            failsafe_steps: self.failsafe,
            failsafe_entries: self.entries,
            rms_att_deg: (self.sum_att / n).sqrt().to_degrees(),
            rms_pos_m: (self.sum_pos / n).sqrt(),
            rms_vel_mps: (self.sum_vel / n).sqrt(),
            max_pos_m: self.max_pos,
            // NaN (null in JSON) where the endpoint reports no covariance.
            nees_mean: self.sum_nees / self.n_nees as f64,
            nees_blocks_mean: self.sum_blocks.map(|v| v / self.n_nees as f64),
            trace,
            counters: self.counters,
        }
    }
}
