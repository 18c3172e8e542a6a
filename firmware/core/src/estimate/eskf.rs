//! The error-state Kalman filter: named steps (screen the sample, propagate
//! the covariance, propagate the nominal state, record it; gate, update,
//! inject, condition), one bounded loop each.

use super::{EskfConfig, EstimatorError, Fix, ImuSample};
use crate::control::StateEstimate;
use crate::model::{euler_to_quat, quat_mul, quat_normalize, quat_to_euler, quat_to_rotation, Quat};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3, Vector4};

/// Size of the error state `[δp δv δθ δb_g δb_a]`.
pub const ERR: usize = 15;

/// Error-state covariance.
type Cov = SMatrix<f32, ERR, ERR>;
/// An error-state vector (a correction, a measurement row).
type ErrVec = SVector<f32, ERR>;

/// Offsets of the error-state blocks.
const IP: usize = 0;
const IV: usize = 3;
const ITH: usize = 6;
const IBG: usize = 9;
const IBA: usize = 12;

/// Largest variance kept per error state (beyond it the number means
/// "unknown" anyway, and f32 stays far from overflow while dead reckoning).
const VAR_MAX: f32 = 1.0e8;
/// 1σ of the velocity after a position reset, m/s.
const RESET_VEL_SIGMA_MPS: f32 = 1.0;
/// 1σ added to each attitude axis at a position reset, rad.
const RESET_ATT_SIGMA_RAD: f32 = 0.1;
/// Smallest variance kept per error state.
const VAR_MIN: f32 = 1.0e-14;

/// Where the filter is in its life.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// Averaging IMU samples at rest and waiting for a position fix and a
    /// heading; no estimate yet.
    Aligning,
    /// Estimating.
    Running,
}

/// What the filter refused or repaired, since it started. Every count is a
/// sample or fix that did *not* enter the estimate (or a repair).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EskfCounters {
    /// IMU samples with NaN/∞ or a gyro beyond its range: replaced by the last good one.
    pub imu_rejected: u32,
    /// IMU samples whose accelerometer had clipped: its specific force replaced by the last good one.
    pub imu_clipped: u32,
    /// Position fixes outside the innovation gate.
    pub pos_rejected: u32,
    /// Velocity fixes outside the innovation gate.
    pub vel_rejected: u32,
    /// Heading fixes outside the innovation gate.
    pub yaw_rejected: u32,
    /// Barometric altitudes outside the innovation gate.
    pub alt_rejected: u32,
    /// Fixes refused before gating (bad age or sigma, non-finite values).
    pub fix_invalid: u32,
    /// Position resets to the fix after `reset_after_rejections` rejections in a row.
    pub pos_resets: u32,
    /// Covariance found non-finite and re-initialised.
    pub covariance_resets: u32,
    /// Fix parts fused (position, velocity, heading and altitude each count one).
    pub fused: u32,
    /// Position fixes fused.
    pub pos_fused: u32,
}

/// The innovation test ratios of the latest fix part of each kind, as PX4's
/// estimator keeps them: per axis innovation² / (gate² · S), S the
/// innovation variance, the largest over the axes named; 0 before the
/// first. (`ESTIMATOR_STATUS` sends their square roots; no root is taken
/// here, on the estimator's step.) A scalar part (heading, altitude) above 1
/// was outside the gate. A position or velocity is gated jointly on its
/// three axes (its normalised innovation squared against gate²), so one
/// axis above 1 does not alone say that it was refused: the counters do.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TestRatios {
    /// Position, north and east.
    pub pos_horiz: f32,
    /// Position, down.
    pub pos_vert: f32,
    /// Velocity, the three axes.
    pub vel: f32,
    /// Heading.
    pub yaw: f32,
    /// Barometric altitude.
    pub alt: f32,
}

/// innov² / (gate² · s); infinite for a variance that is not positive.
fn test_ratio(innov: f32, s: f32, gate: f32) -> f32 {
    let d = gate * gate * s;
    if d > 0.0 {
        innov * innov / d
    } else {
        f32::INFINITY
    }
}

/// The nominal state at one past step, for delayed fixes.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Past {
    p: Vector3<f32>,
    v: Vector3<f32>,
    q: Quat<f32>,
    /// The step that led to this state, s.
    dt: f32,
}

const PAST_ZERO: Past = Past {
    p: Vector3::new(0.0, 0.0, 0.0),
    v: Vector3::new(0.0, 0.0, 0.0),
    q: Vector4::new(1.0, 0.0, 0.0, 0.0),
    dt: 0.0,
};

/// The error-state Kalman filter with a history of `H` steps for delayed
/// fixes (`H × dt` must exceed the slowest source's latency: 128 steps at
/// 500 Hz cover 256 ms). See the module documentation.
#[derive(Debug, Clone)]
pub struct Eskf<const H: usize> {
    cfg: EskfConfig,
    mode: Mode,
    /// Position, NED, m.
    p: Vector3<f32>,
    /// Velocity, NED, m/s.
    v: Vector3<f32>,
    /// Attitude body FRD → NED, scalar first.
    q: Quat<f32>,
    /// Gyro bias, FRD, rad/s.
    bg: Vector3<f32>,
    /// Accelerometer bias, FRD, m/s².
    ba: Vector3<f32>,
    cov: Cov,
    /// The last good IMU sample (what replaces a bad one).
    last_imu: Option<ImuSample>,
    /// The sample the previous step was flown on.
    prev_imu: Option<ImuSample>,
    hist: [Past; H],
    /// Index of the newest history entry.
    head: usize,
    /// Entries in use.
    len: usize,
    // Alignment: sums of the samples at rest, and the latest fix parts.
    align_n: u16,
    align_f: Vector3<f32>,
    align_w: Vector3<f32>,
    align_pos: Option<(Vector3<f32>, Vector3<f32>)>,
    align_yaw: Option<f32>,
    /// Position fixes rejected in a row.
    rejected_run: u16,
    counters: EskfCounters,
    ratios: TestRatios,
}

impl<const H: usize> Eskf<H> {
    /// A filter waiting to align. `Err` names a bad setting; `H` must be ≥ 1
    /// (checked at compile time).
    pub fn new(cfg: EskfConfig) -> Result<Self, EstimatorError> {
        cfg.check()?;
        Ok(Self::new_unchecked(cfg))
    }

    /// A filter with settings the caller has checked ([`EskfConfig::check`]).
    pub fn new_unchecked(cfg: EskfConfig) -> Self {
        const { assert!(H >= 1, "the history needs at least one entry") };
        Self {
            cfg,
            mode: Mode::Aligning,
            p: Vector3::zeros(),
            v: Vector3::zeros(),
            q: Vector4::new(1.0, 0.0, 0.0, 0.0),
            bg: Vector3::zeros(),
            ba: Vector3::zeros(),
            cov: Cov::identity(),
            last_imu: None,
            prev_imu: None,
            hist: [PAST_ZERO; H],
            head: 0,
            len: 0,
            align_n: 0,
            align_f: Vector3::zeros(),
            align_w: Vector3::zeros(),
            align_pos: None,
            align_yaw: None,
            rejected_run: 0,
            counters: EskfCounters::default(),
            ratios: TestRatios::default(),
        }
    }

    /// Back to aligning, everything learnt forgotten, in place (the filter
    /// is large: no temporary copy of it is made); the counters stay.
    pub fn reset(&mut self) {
        self.mode = Mode::Aligning;
        self.p = Vector3::zeros();
        self.v = Vector3::zeros();
        self.q = Vector4::new(1.0, 0.0, 0.0, 0.0);
        self.bg = Vector3::zeros();
        self.ba = Vector3::zeros();
        self.cov = Cov::identity();
        self.last_imu = None;
        self.prev_imu = None;
        self.head = 0;
        self.len = 0;
        self.align_n = 0;
        self.align_f = Vector3::zeros();
        self.align_w = Vector3::zeros();
        self.align_pos = None;
        self.align_yaw = None;
        self.rejected_run = 0;
    }

    /// Starts running from a given estimate (skipping alignment), with 1σ
    /// uncertainties of its position (m), velocity (m/s) and attitude (rad);
    /// the biases start at zero with their configured uncertainty.
    pub fn start_at(
        &mut self,
        est: &StateEstimate<f32>,
        pos_sigma_m: f32,
        vel_sigma_mps: f32,
        att_sigma_rad: f32,
    ) -> Result<(), EstimatorError> {
        let sig = [pos_sigma_m, vel_sigma_mps, att_sigma_rad];
        if !est.is_valid() || !sig.iter().all(|s| s.is_finite() && *s > 0.0) {
            return Err(EstimatorError::Initial);
        }
        self.p = est.pos_ned_m;
        self.v = est.vel_ned_mps;
        self.q = quat_normalize(&est.att);
        self.bg = Vector3::zeros();
        self.ba = Vector3::zeros();
        self.cov = self.initial_cov(&Vector3::repeat(pos_sigma_m), vel_sigma_mps, att_sigma_rad);
        self.mode = Mode::Running;
        self.len = 0;
        self.record(0.0);
        Ok(())
    }

    /// Aligning or running.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// What was refused or repaired so far.
    pub fn counters(&self) -> EskfCounters {
        self.counters
    }

    /// The latest fixes' innovation test ratios.
    pub fn test_ratios(&self) -> TestRatios {
        self.ratios
    }

    /// The error-state covariance `[δp δv δθ δb_g δb_a]` (m, m/s, rad, rad/s, m/s²).
    pub fn covariance(&self) -> &SMatrix<f32, ERR, ERR> {
        &self.cov
    }

    /// 1σ of each error state (the covariance's diagonal, square-rooted).
    pub fn sigmas(&self) -> SVector<f32, ERR> {
        self.cov.diagonal().map(libm::sqrtf)
    }

    /// The largest 1σ of the three position axes, m (the failsafe's measure).
    pub fn position_sigma_m(&self) -> f32 {
        let d = self.cov.diagonal();
        libm::sqrtf(d[IP].max(d[IP + 1]).max(d[IP + 2]))
    }

    /// Gyro bias (FRD, rad/s) and accelerometer bias (FRD, m/s²) estimates.
    pub fn biases(&self) -> (Vector3<f32>, Vector3<f32>) {
        (self.bg, self.ba)
    }

    /// The estimate the controllers read: position, velocity, attitude, and
    /// the body rates of the last IMU sample less the gyro bias.
    pub fn estimate(&self) -> Result<StateEstimate<f32>, EstimatorError> {
        match (self.mode, self.last_imu) {
            (Mode::Running, Some(s)) => Ok(StateEstimate {
                pos_ned_m: self.p,
                vel_ned_mps: self.v,
                att: self.q,
                rates_frd_radps: s.gyro_frd_radps - self.bg,
            }),
            (Mode::Running, None) => Ok(StateEstimate {
                pos_ned_m: self.p,
                vel_ned_mps: self.v,
                att: self.q,
                rates_frd_radps: Vector3::zeros(),
            }),
            (Mode::Aligning, _) => Err(EstimatorError::NotAligned),
        }
    }

    /// One IMU step of `dt_s` seconds (the sample is held over the step).
    /// A bad sample is counted and replaced by the last good one; while
    /// aligning, the good samples are averaged.
    pub fn predict(&mut self, imu: &ImuSample, dt_s: f32) -> Result<(), EstimatorError> {
        if !(dt_s.is_finite() && dt_s > 0.0 && dt_s <= 0.1) {
            return Err(EstimatorError::Step);
        }
        let good = self.screen(imu);
        if self.mode == Mode::Aligning {
            if good {
                self.align_n = self.align_n.saturating_add(1);
                self.align_f += imu.accel_frd_mps2;
                self.align_w += imu.gyro_frd_radps;
            }
            self.try_align();
            return Ok(());
        }
        let Some(s) = self.last_imu else {
            return Ok(());
        };
        // The sample is held over the step; how much the signal moved since
        // the one before says how far the truth may have moved within it.
        let df = match self.prev_imu.replace(s) {
            Some(p) => (s.accel_frd_mps2 - p.accel_frd_mps2).norm_squared(),
            None => 0.0,
        };
        let w = s.gyro_frd_radps - self.bg;
        let f = s.accel_frd_mps2 - self.ba;
        let r = quat_to_rotation(&self.q);
        let f_ned = r * f;
        self.propagate_covariance(&r, &f_ned, dt_s, df);
        let acc = f_ned + Vector3::new(0.0, 0.0, self.cfg.gravity_mps2);
        self.p += self.v * dt_s + acc * (0.5 * dt_s * dt_s);
        self.v += acc * dt_s;
        self.q = quat_normalize(&quat_mul(&self.q, &rotation_quat(&(w * dt_s))));
        self.record(dt_s);
        Ok(())
    }

    /// Fuses a fix (every part it has). Parts outside the gate are counted
    /// and dropped; a fix with a bad age or sigma is refused whole (counted).
    /// While aligning, the fix's position and heading are kept for the
    /// alignment.
    pub fn fuse(&mut self, fix: &Fix) -> Result<(), EstimatorError> {
        if let Err(e) = check_fix(fix) {
            self.counters.fix_invalid += 1;
            return Err(e);
        }
        if self.mode == Mode::Aligning {
            if let Some(pos) = fix.pos_ned_m {
                self.align_pos = Some((pos, fix.pos_sigma_m));
            }
            if let Some(yaw) = fix.yaw_rad {
                self.align_yaw = Some(yaw);
            }
            self.try_align();
            return Ok(());
        }
        let Some(past) = self.past(fix.age_s) else {
            if self.len < H {
                // Taken before the filter started (in transit during the
                // alignment): nothing to compare it with, nothing wrong.
                return Ok(());
            }
            self.counters.fix_invalid += 1;
            return Err(EstimatorError::FixAge);
        };
        let mut dx = ErrVec::zeros();
        if let Some(z) = fix.pos_ned_m {
            self.fuse_triple(&mut dx, IP, &(z - past.p), &fix.pos_sigma_m, true);
        }
        if let Some(z) = fix.vel_ned_mps {
            self.fuse_triple(&mut dx, IV, &(z - past.v), &Vector3::repeat(fix.vel_sigma_mps), false);
        }
        if let Some(yaw) = fix.yaw_rad {
            let r = quat_to_rotation(&self.q);
            let (r00, r10, r20) = (r[(0, 0)], r[(1, 0)], r[(2, 0)]);
            let n = (r00 * r00 + r10 * r10).max(1e-6);
            // ∂ψ/∂δθ for a rotation δθ in NED (docs/book/src/model.md §11).
            let h = [(ITH, -r20 * r00 / n), (ITH + 1, -r20 * r10 / n), (ITH + 2, 1.0)];
            let y = crate::control::wrap_pi(yaw - quat_to_euler(&past.q)[2]);
            let sig = fix.yaw_sigma_rad;
            let (fused, ratio) = self.scalar_update(&mut dx, &h, y, sig * sig);
            self.ratios.yaw = ratio;
            if fused {
                self.counters.fused += 1;
            } else {
                self.counters.yaw_rejected += 1;
            }
        }
        if let Some(alt) = fix.alt_m {
            let h = [(IP + 2, -1.0)];
            let sig = fix.alt_sigma_m;
            let (fused, ratio) = self.scalar_update(&mut dx, &h, alt + past.p[2], sig * sig);
            self.ratios.alt = ratio;
            if fused {
                self.counters.fused += 1;
            } else {
                self.counters.alt_rejected += 1;
            }
        }
        self.inject(&dx);
        self.condition();
        Ok(())
    }

    // ---- steps ---------------------------------------------------------

    /// Keeps `imu` as the last good sample if it is; returns whether it was.
    fn screen(&mut self, imu: &ImuSample) -> bool {
        let finite = imu
            .gyro_frd_radps
            .iter()
            .chain(imu.accel_frd_mps2.iter())
            .all(|v| v.is_finite());
        if !finite || imu.gyro_frd_radps.amax() > self.cfg.gyro_range_radps {
            self.counters.imu_rejected += 1;
            return false;
        }
        if imu.accel_frd_mps2.amax() >= 0.999 * self.cfg.accel_range_mps2 {
            self.counters.imu_clipped += 1;
            // The rates are good; the specific force is not.
            if let Some(last) = self.last_imu.as_mut() {
                last.gyro_frd_radps = imu.gyro_frd_radps;
            }
            return false;
        }
        self.last_imu = Some(*imu);
        true
    }

    /// Once enough samples at rest, a position and a heading are in:
    /// roll and pitch from the mean specific force, gyro bias from the mean
    /// rate, heading and position from the fixes.
    fn try_align(&mut self) {
        let (Some((pos, pos_sigma)), Some(yaw)) = (self.align_pos, self.align_yaw) else {
            return;
        };
        if self.align_n < self.cfg.align_samples {
            return;
        }
        let n = f32::from(self.align_n);
        let f = self.align_f / n;
        let phi = libm::atan2f(-f[1], -f[2]);
        let theta = libm::atan2f(f[0], libm::sqrtf(f[1] * f[1] + f[2] * f[2]));
        self.q = euler_to_quat(phi, theta, yaw);
        self.p = pos;
        self.v = Vector3::zeros();
        self.bg = self.align_w / n;
        self.ba = Vector3::zeros();
        let c = self.cfg;
        self.cov = self.initial_cov(&pos_sigma, c.init_vel_sigma_mps, c.init_att_sigma_rad);
        self.mode = Mode::Running;
        self.len = 0;
        self.record(0.0);
    }

    fn initial_cov(&self, pos_sigma: &Vector3<f32>, vel_sigma: f32, att_sigma: f32) -> Cov {
        let c = &self.cfg;
        let mut d = ErrVec::zeros();
        for i in 0..3 {
            d[IP + i] = pos_sigma[i] * pos_sigma[i];
            d[IV + i] = vel_sigma * vel_sigma;
            d[ITH + i] = att_sigma * att_sigma;
            d[IBG + i] = c.init_gyro_bias_sigma * c.init_gyro_bias_sigma;
            d[IBA + i] = c.init_accel_bias_sigma_xy * c.init_accel_bias_sigma_xy;
        }
        d[IBA + 2] = c.init_accel_bias_sigma_z * c.init_accel_bias_sigma_z;
        Cov::from_diagonal(&d)
    }

    /// `P ← F P Fᵀ + Q` with `F = I + A·dt` applied as its four non-zero
    /// blocks (`δṗ = δv`, `δv̇ = −[f]× δθ − R δb_a`, `δθ̇ = −R δb_g`):
    /// `F (F P)ᵀ` is `F P Fᵀ` for a symmetric `P`.
    ///
    /// `Q` is the IMU's white noise and bias walks, plus the hold's own
    /// error: the specific force may have moved within the step by as much
    /// as it moved between the last two samples (`df`: the squared norm of
    /// that change less what the white noise explains), a uniform
    /// `(Δf·dt)²/3` on velocity. (Thrust steps of a controller land between
    /// samples; the same term for the rates made the attitude worse, not
    /// more consistent, and is not used.)
    fn propagate_covariance(&mut self, r: &Matrix3<f32>, f_ned: &Vector3<f32>, dt: f32, df: f32) {
        apply_transition(&mut self.cov, r, f_ned, dt);
        self.cov.transpose_mut();
        apply_transition(&mut self.cov, r, f_ned, dt);
        let c = &self.cfg;
        // The part of a change that the samples' own white noise explains
        // (2 samples × 3 axes × density²/dt) is not a change of the signal.
        let df = (df - 6.0 * c.accel_noise * c.accel_noise / dt).max(0.0);
        let qv = c.accel_noise * c.accel_noise * dt + df * dt * dt / 3.0;
        let qth = c.gyro_noise * c.gyro_noise * dt;
        let qbg = c.gyro_bias_walk * c.gyro_bias_walk * dt;
        let qba = c.accel_bias_walk * c.accel_bias_walk * dt;
        for i in 0..3 {
            self.cov[(IV + i, IV + i)] += qv;
            self.cov[(ITH + i, ITH + i)] += qth;
            self.cov[(IBG + i, IBG + i)] += qbg;
            self.cov[(IBA + i, IBA + i)] += qba;
        }
        self.condition();
    }

    /// Pushes the nominal state after a step of `dt` into the history.
    fn record(&mut self, dt: f32) {
        self.head = (self.head + 1) % H;
        self.hist[self.head] = Past {
            p: self.p,
            v: self.v,
            q: self.q,
            dt,
        };
        self.len = (self.len + 1).min(H);
    }

    /// The nominal state `age` seconds ago (the entry nearest that time);
    /// `None` if the history does not reach back that far.
    fn past(&self, age: f32) -> Option<Past> {
        let mut back = 0usize;
        let mut t = 0.0f32;
        while back + 1 < self.len {
            let e = &self.hist[(self.head + H - back) % H];
            if t + 0.5 * e.dt >= age {
                break;
            }
            t += e.dt;
            back += 1;
        }
        let e = self.hist[(self.head + H - back) % H];
        // The oldest entry is only good if the fix is not older still.
        (t + 0.5 * e.dt.max(1e-3) >= age || back + 1 < self.len).then_some(e)
    }

    /// Position or velocity: a joint gate on the three innovations, then
    /// three scalar updates. A rejected position counts towards a reset.
    fn fuse_triple(&mut self, dx: &mut ErrVec, at: usize, y: &Vector3<f32>, sigma: &Vector3<f32>, pos: bool) {
        let mut s = self.cov.fixed_view::<3, 3>(at, at).into_owned();
        for i in 0..3 {
            s[(i, i)] += sigma[i] * sigma[i];
        }
        let gate = self.cfg.gate_sigma;
        let r = Vector3::from_fn(|i, _| test_ratio(y[i], s[(i, i)], gate));
        if pos {
            self.ratios.pos_horiz = r[0].max(r[1]);
            self.ratios.pos_vert = r[2];
        } else {
            self.ratios.vel = r.max();
        }
        let nis = match s.try_inverse() {
            Some(si) => (y.transpose() * si * y)[0],
            None => f32::INFINITY,
        };
        if !(nis.is_finite() && nis <= gate * gate) {
            if pos {
                self.counters.pos_rejected += 1;
                self.rejected_run = self.rejected_run.saturating_add(1);
                if self.rejected_run >= self.cfg.reset_after_rejections {
                    self.reset_position(y, sigma);
                }
            } else {
                self.counters.vel_rejected += 1;
            }
            return;
        }
        if pos {
            self.rejected_run = 0;
            self.counters.pos_fused += 1;
        }
        for i in 0..3 {
            // Gated jointly above.
            let _ = self.scalar_update_with(dx, &[(at + i, 1.0)], y[i], sigma[i] * sigma[i], false);
        }
        self.counters.fused += 1;
    }

    /// Believes the fix: moves the position by the innovation, forgets what
    /// the filter knew of its position and velocity (a filter that lost its
    /// fixes has lost both), and widens its attitude uncertainty so that the
    /// fixes that follow can correct a tilt that caused the drift (counted).
    fn reset_position(&mut self, y: &Vector3<f32>, sigma: &Vector3<f32>) {
        self.p += y;
        let vel_var = RESET_VEL_SIGMA_MPS * RESET_VEL_SIGMA_MPS;
        for i in 0..3 {
            for j in 0..ERR {
                self.cov[(IP + i, j)] = 0.0;
                self.cov[(j, IP + i)] = 0.0;
                self.cov[(IV + i, j)] = 0.0;
                self.cov[(j, IV + i)] = 0.0;
            }
            self.cov[(IP + i, IP + i)] = sigma[i] * sigma[i];
            self.cov[(IV + i, IV + i)] = vel_var;
            self.cov[(ITH + i, ITH + i)] += RESET_ATT_SIGMA_RAD * RESET_ATT_SIGMA_RAD;
        }
        self.rejected_run = 0;
        self.counters.pos_resets += 1;
    }

    /// `P hᵀ` for a sparse measurement row `h` (index, coefficient).
    fn cov_h(&self, h: &[(usize, f32)]) -> ErrVec {
        let mut ph = ErrVec::zeros();
        for &(j, c) in h {
            ph += self.cov.column(j) * c;
        }
        ph
    }

    /// One gated scalar update with the sparse row `h`: whether it was
    /// fused (`false`: nothing changed, outside the gate), and its test
    /// ratio ([`TestRatios`]).
    fn scalar_update(&mut self, dx: &mut ErrVec, h: &[(usize, f32)], y: f32, r: f32) -> (bool, f32) {
        self.scalar_update_with(dx, h, y, r, true)
    }

    /// One scalar update, behind the scalar gate when `gated` (a part
    /// gated jointly beforehand is not): whether it was fused, and its test
    /// ratio when gated here (0 otherwise: the joint gate takes its own).
    fn scalar_update_with(&mut self, dx: &mut ErrVec, h: &[(usize, f32)], y: f32, r: f32, gated: bool) -> (bool, f32) {
        let ph = self.cov_h(h);
        let s = sparse_dot(h, &ph) + r;
        let innov = y - sparse_dot(h, dx);
        let gate = self.cfg.gate_sigma;
        let ratio = if gated { test_ratio(innov, s, gate) } else { 0.0 };
        if !(s > 0.0 && (!gated || innov * innov <= gate * gate * s)) {
            return (false, ratio);
        }
        (self.apply_gain(dx, &ph, s, innov), ratio)
    }

    /// `K = P hᵀ / s`, `δx += K·innov`, `P −= K (P hᵀ)ᵀ` (symmetric: the
    /// lower triangle is computed and mirrored).
    fn apply_gain(&mut self, dx: &mut ErrVec, ph: &ErrVec, s: f32, innov: f32) -> bool {
        if !(s.is_finite() && innov.is_finite()) {
            return false;
        }
        let k = ph / s;
        *dx += k * innov;
        for j in 0..ERR {
            let pj = ph[j];
            for i in j..ERR {
                let v = self.cov[(i, j)] - k[i] * pj;
                self.cov[(i, j)] = v;
                self.cov[(j, i)] = v;
            }
        }
        true
    }

    /// Moves the nominal state by the accumulated correction.
    fn inject(&mut self, dx: &ErrVec) {
        if !dx.iter().all(|v| v.is_finite()) {
            return;
        }
        self.p += dx.fixed_rows::<3>(IP);
        self.v += dx.fixed_rows::<3>(IV);
        let dth: Vector3<f32> = dx.fixed_rows::<3>(ITH).into_owned();
        self.q = quat_normalize(&quat_mul(&rotation_quat(&dth), &self.q));
        self.bg += dx.fixed_rows::<3>(IBG);
        self.ba += dx.fixed_rows::<3>(IBA);
    }

    /// Symmetric, with its diagonal in `[VAR_MIN, VAR_MAX]`; re-initialised
    /// (counted) if anything in it is not finite.
    fn condition(&mut self) {
        if !self.cov.iter().all(|v| v.is_finite()) {
            let c = self.cfg;
            self.cov = self.initial_cov(&Vector3::repeat(1.0), 1.0, c.init_att_sigma_rad.max(0.1));
            self.counters.covariance_resets += 1;
            return;
        }
        for i in 0..ERR {
            for j in (i + 1)..ERR {
                let m = 0.5 * (self.cov[(i, j)] + self.cov[(j, i)]);
                self.cov[(i, j)] = m;
                self.cov[(j, i)] = m;
            }
            let d = self.cov[(i, i)];
            self.cov[(i, i)] = d.clamp(VAR_MIN, VAR_MAX);
        }
    }
}

/// `h · v` for a sparse row `h`.
fn sparse_dot(h: &[(usize, f32)], v: &ErrVec) -> f32 {
    h.iter().map(|&(j, c)| c * v[j]).sum()
}

/// `M ← F M` for `F = I + A·dt`, column by column, in place: each row
/// block reads only blocks that are updated after it.
fn apply_transition(m: &mut Cov, r: &Matrix3<f32>, f_ned: &Vector3<f32>, dt: f32) {
    for j in 0..ERR {
        let mut c = m.column_mut(j);
        let vel = Vector3::new(c[IV], c[IV + 1], c[IV + 2]);
        let th = Vector3::new(c[ITH], c[ITH + 1], c[ITH + 2]);
        let bg = Vector3::new(c[IBG], c[IBG + 1], c[IBG + 2]);
        let ba = Vector3::new(c[IBA], c[IBA + 1], c[IBA + 2]);
        let fxth = f_ned.cross(&th);
        let rbg = r * bg;
        let rba = r * ba;
        for i in 0..3 {
            c[IP + i] += dt * vel[i];
            c[IV + i] -= dt * (fxth[i] + rba[i]);
            c[ITH + i] -= dt * rbg[i];
        }
    }
}

/// The unit quaternion of the rotation vector `a` (rad): `exp(a/2)`.
pub(crate) fn rotation_quat(a: &Vector3<f32>) -> Quat<f32> {
    let angle = fc_fpu::sqrt(a.norm_squared());
    if angle < 1e-6 {
        return quat_normalize(&Vector4::new(1.0, 0.5 * a[0], 0.5 * a[1], 0.5 * a[2]));
    }
    let (s, c) = crate::math::sin_cos_f32(0.5 * angle);
    let k = s / angle;
    Vector4::new(c, k * a[0], k * a[1], k * a[2])
}

/// Refuses a fix with a bad age, sigma or value.
fn check_fix(fix: &Fix) -> Result<(), EstimatorError> {
    if !(fix.age_s.is_finite() && fix.age_s >= 0.0) {
        return Err(EstimatorError::FixAge);
    }
    let ok = |s: f32| s.is_finite() && s > 0.0;
    let finite3 = |v: &Vector3<f32>| v.iter().all(|x| x.is_finite());
    if let Some(p) = fix.pos_ned_m {
        if !fix.pos_sigma_m.iter().all(|s| ok(*s)) {
            return Err(EstimatorError::FixSigma);
        }
        if !finite3(&p) {
            return Err(EstimatorError::FixValue);
        }
    }
    if let Some(v) = fix.vel_ned_mps {
        if !ok(fix.vel_sigma_mps) {
            return Err(EstimatorError::FixSigma);
        }
        if !finite3(&v) {
            return Err(EstimatorError::FixValue);
        }
    }
    if let Some(y) = fix.yaw_rad {
        if !ok(fix.yaw_sigma_rad) {
            return Err(EstimatorError::FixSigma);
        }
        if !y.is_finite() {
            return Err(EstimatorError::FixValue);
        }
    }
    if let Some(a) = fix.alt_m {
        if !ok(fix.alt_sigma_m) {
            return Err(EstimatorError::FixSigma);
        }
        if !a.is_finite() {
            return Err(EstimatorError::FixValue);
        }
    }
    Ok(())
}

#[cfg(test)]
mod transition_tests {
    use super::*;
    use crate::estimate::EskfConfig;

    /// The nominal state as an error-state difference `b ⊖ a` (NED rotation vector).
    fn difference(a: &Eskf<8>, b: &Eskf<8>) -> ErrVec {
        let mut d = ErrVec::zeros();
        d.fixed_rows_mut::<3>(IP).copy_from(&(b.p - a.p));
        d.fixed_rows_mut::<3>(IV).copy_from(&(b.v - a.v));
        let dq = quat_mul(&b.q, &crate::model::quat_conj(&a.q));
        let s = if dq[0] < 0.0 { -2.0 } else { 2.0 };
        d.fixed_rows_mut::<3>(ITH)
            .copy_from(&(Vector3::new(dq[1], dq[2], dq[3]) * s));
        d.fixed_rows_mut::<3>(IBG).copy_from(&(b.bg - a.bg));
        d.fixed_rows_mut::<3>(IBA).copy_from(&(b.ba - a.ba));
        d
    }

    /// The transition the covariance is propagated with is the Jacobian of
    /// the nominal propagation: perturb each error state, propagate both
    /// nominal states with the same IMU sample, compare with `F·δx`.
    #[test]
    fn the_transition_matrix_is_the_jacobian_of_the_propagation() {
        let mut base = Eskf::<8>::new(EskfConfig::BMI088).unwrap();
        let est = StateEstimate {
            pos_ned_m: Vector3::new(0.1, -0.2, -0.3),
            vel_ned_mps: Vector3::new(0.5, -1.0, 0.3),
            att: euler_to_quat(0.3, -0.2, 1.1),
            rates_frd_radps: Vector3::zeros(),
        };
        base.start_at(&est, 0.1, 0.1, 0.1).unwrap();
        base.bg = Vector3::new(0.01, -0.02, 0.03);
        base.ba = Vector3::new(0.05, -0.03, 0.2);
        let imu = ImuSample {
            gyro_frd_radps: Vector3::new(0.7, -0.4, 0.9),
            accel_frd_mps2: Vector3::new(1.5, -2.0, -11.0),
        };
        let dt = 0.01;
        let h = 1e-2;
        for k in 0..ERR {
            let mut dx = ErrVec::zeros();
            dx[k] = h;
            let mut pert = base.clone();
            pert.inject(&dx);
            let (mut a, mut b) = (base.clone(), pert.clone());
            a.predict(&imu, dt).unwrap();
            b.predict(&imu, dt).unwrap();
            let got = difference(&a, &b);
            let r = quat_to_rotation(&base.q);
            let f_ned = r * (imu.accel_frd_mps2 - base.ba);
            let mut m = Cov::zeros();
            m.set_column(0, &dx);
            apply_transition(&mut m, &r, &f_ned, dt);
            // Compare what one step adds to the perturbation: first order in
            // dt and h, the rest O(dt²·h) + O(h²·dt) + f32 rounding.
            let inc_want = m.column(0) - dx;
            let inc_got = got - dx;
            let err = (inc_got - inc_want).amax();
            assert!(
                err < 0.05 * inc_want.amax() + 2e-6,
                "column {k}: step adds {inc_got:?}, F·δx adds {inc_want:?}"
            );
            // Every state but the position moves something else in one step.
            assert!(inc_want.amax() > 1e-5 || k < IV, "column {k} did not propagate");
        }
    }
}
