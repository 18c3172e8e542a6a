//! Flying from sensors: the estimator between the IMU and fix messages and
//! the controllers, its alignment, and the failsafe that trusts it only as
//! far as it deserves.
//!
//! Per IMU sample (1 kHz; the controller runs on its own, slower
//! [`crate::schedule::Schedule`]): predict over the time since the last
//! sample, fuse the fixes that arrived, then decide the mode:
//! - [`NavMode::Aligning`]: no estimate yet (waiting for samples at rest, a
//!   position and a heading): the caller holds hover thrust, no torque;
//! - [`NavMode::Navigating`]: the controllers fly the estimate and the
//!   mission's setpoint;
//! - [`NavMode::Failsafe`]: the position is not trusted: its 1σ has been
//!   above `max_position_sigma_m` for `sigma_grace_s`, or no position fix
//!   has been fused for `dead_reckoning_limit_s` (PX4's `EKF2_NOAID_TOUT`
//!   idea: dead reckoning is believed for a bounded time). The controllers
//!   then fly [`Navigator::setpoint`]: hold the estimated position where
//!   the failsafe began, level, descending at `descent_mps`. When fixes are
//!   fused again and the position 1σ is back under the bound, the mission
//!   resumes.

use fc_core::control::{Controller, Setpoint, StateEstimate};
use fc_core::estimate::{Eskf, EskfConfig, EskfCounters, EstimatorError, Fix, ImuSample, Mode};
use nalgebra::Vector3;

/// Steps of estimator history for delayed fixes (128 ms at 1 kHz).
pub const HISTORY: usize = 128;

/// Most scalar updates one fix part brings to a step: a fix with more (a
/// mocap fix with position and heading, 4; a gps fix with position and
/// velocity, 6) is split into parts of at most this many, fused one part
/// per IMU step, so that the worst step is a predict and one such part
/// (the budget's `navigator` row).
pub const MAX_UPDATES_PER_STEP: usize = 3;

/// Fix parts waiting for their step; more are dropped and counted
/// ([`Navigator::fixes_dropped`]). Sensors deliver a few parts per 10 ms:
/// the queue drains at one part per step.
pub const PENDING_PARTS: usize = 6;

/// The arrival time of a part queued between steps: stamped at the next.
const UNSTAMPED: u64 = u64::MAX;

/// The scalar updates a fix brings: 3 per triple, 1 per scalar.
pub fn updates_of(f: &Fix) -> usize {
    3 * usize::from(f.pos_ned_m.is_some())
        + 3 * usize::from(f.vel_ned_mps.is_some())
        + usize::from(f.yaw_rad.is_some())
        + usize::from(f.alt_m.is_some())
}

/// `f` whole if it brings at most [`MAX_UPDATES_PER_STEP`] updates; else
/// its position, its velocity, and its heading with its altitude, each
/// part that has anything.
fn parts_of(f: &Fix) -> [Option<Fix>; 3] {
    if updates_of(f) <= MAX_UPDATES_PER_STEP {
        return [Some(*f), None, None];
    }
    let only = |keep: [bool; 4]| {
        let part = Fix {
            pos_ned_m: f.pos_ned_m.filter(|_| keep[0]),
            vel_ned_mps: f.vel_ned_mps.filter(|_| keep[1]),
            yaw_rad: f.yaw_rad.filter(|_| keep[2]),
            alt_m: f.alt_m.filter(|_| keep[3]),
            ..*f
        };
        (updates_of(&part) > 0).then_some(part)
    };
    [
        only([true, false, false, false]),
        only([false, true, false, false]),
        only([false, false, true, true]),
    ]
}

/// The navigator's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavConfig {
    /// The estimator's.
    pub eskf: EskfConfig,
    /// Position 1σ (largest axis) above which the position is not trusted, m.
    pub max_position_sigma_m: f32,
    /// How long the 1σ may stay above the bound before the failsafe, s.
    pub sigma_grace_s: f32,
    /// No position fix fused for this long → failsafe, s.
    pub dead_reckoning_limit_s: f32,
    /// Failsafe descent speed, m/s.
    pub descent_mps: f32,
    /// The IMU's sample period, s: the step of the first sample (the later
    /// ones are measured from the samples' times).
    pub imu_period_s: f32,
    /// Longest step integrated, s (from `imu_period_s` to 0.1): a longer gap between samples (a link or
    /// sensor outage) is integrated as this long; the fixes correct the rest.
    pub max_imu_gap_s: f32,
}

impl Default for NavConfig {
    fn default() -> Self {
        Self {
            eskf: EskfConfig::BMI088,
            max_position_sigma_m: 1.0,
            sigma_grace_s: 0.5,
            dead_reckoning_limit_s: 5.0,
            descent_mps: 0.3,
            imu_period_s: 0.001,
            max_imu_gap_s: 0.02,
        }
    }
}

impl NavConfig {
    /// `Err` naming the first setting that is not finite and positive.
    pub fn check(&self) -> Result<(), EstimatorError> {
        self.eskf.check()?;
        let fields = [
            ("max_position_sigma_m", self.max_position_sigma_m),
            ("sigma_grace_s", self.sigma_grace_s),
            ("dead_reckoning_limit_s", self.dead_reckoning_limit_s),
            ("descent_mps", self.descent_mps),
            ("imu_period_s", self.imu_period_s),
            ("max_imu_gap_s", self.max_imu_gap_s),
        ];
        fc_core::estimate::check_positive(&fields)?;
        // The estimator integrates at most 0.1 s in one step.
        if !(self.imu_period_s..=0.1).contains(&self.max_imu_gap_s) {
            return Err(EstimatorError::Config("max_imu_gap_s"));
        }
        Ok(())
    }
}

/// What the navigator lets the controllers do this step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NavMode {
    /// No estimate yet: hold hover thrust, no torque.
    Aligning,
    /// Fly the mission on the estimate.
    Navigating,
    /// Position not trusted: fly [`Navigator::setpoint`]'s hold-and-descend.
    Failsafe,
}

/// The estimator and its failsafe.
#[derive(Debug, Clone)]
pub struct Navigator {
    cfg: NavConfig,
    eskf: Eskf<HISTORY>,
    mode: NavMode,
    /// Time of the last fused position fix, µs.
    last_pos_us: Option<u64>,
    /// Time of the last IMU sample, µs.
    last_imu_us: Option<u64>,
    /// Fix parts waiting for a step, with when they arrived (µs).
    pending: heapless::Deque<(Fix, u64), PENDING_PARTS>,
    /// Fix parts dropped because the queue was full.
    dropped: u32,
    /// Since when the position 1σ has been over the bound, µs.
    over_since_us: Option<u64>,
    /// Where and when the failsafe began: position (NED, m), heading, µs.
    failsafe_from: Option<(Vector3<f32>, f32, u64)>,
    entries: u32,
    /// A state given from outside, flown in place of the estimate
    /// ([`Navigator::set_truth`]; host builds with `truth-state` only).
    #[cfg(feature = "truth-state")]
    truth: Option<StateEstimate<f32>>,
}

impl Navigator {
    /// A navigator waiting to align. `Err` names a bad setting.
    pub fn new(cfg: NavConfig) -> Result<Self, EstimatorError> {
        cfg.check()?;
        Ok(Self::with(cfg, Eskf::new(cfg.eskf)?))
    }

    /// The default navigator (BMI088, the default failsafe), which cannot
    /// fail: its settings are valid (`tests::the_default_settings_are_valid`).
    pub fn bmi088() -> Self {
        let cfg = NavConfig::default();
        Self::with(cfg, Eskf::new_unchecked(cfg.eskf))
    }

    /// A navigator of `cfg` around `eskf`, waiting to align (inlined: the
    /// firmware builds it in its static home, not on the stack).
    #[inline(always)]
    fn with(cfg: NavConfig, eskf: Eskf<HISTORY>) -> Self {
        Self {
            cfg,
            eskf,
            mode: NavMode::Aligning,
            last_pos_us: None,
            last_imu_us: None,
            pending: heapless::Deque::new(),
            dropped: 0,
            over_since_us: None,
            failsafe_from: None,
            entries: 0,
            #[cfg(feature = "truth-state")]
            truth: None,
        }
    }

    /// Forgets the flight (a new session is a new time line), in place.
    pub fn reset(&mut self) {
        self.eskf.reset();
        self.mode = NavMode::Aligning;
        self.last_pos_us = None;
        self.last_imu_us = None;
        self.pending.clear();
        self.over_since_us = None;
        self.failsafe_from = None;
        #[cfg(feature = "truth-state")]
        {
            self.truth = None;
        }
    }

    /// One IMU sample taken at `now_us` (µs, increasing) and the fixes that
    /// arrived since the last: the estimator integrates the time since the
    /// previous sample ([`NavConfig::imu_period_s`] for the first, at most
    /// [`NavConfig::max_imu_gap_s`]), then fuses one waiting fix part (aged
    /// by its wait; see [`MAX_UPDATES_PER_STEP`]). A refused fix is counted
    /// by the estimator and changes nothing; `Err` only for a time that does
    /// not increase (nothing is integrated then).
    pub fn step(&mut self, now_us: u64, imu: &ImuSample, fixes: &[Fix]) -> Result<NavMode, EstimatorError> {
        let dt_s = match self.last_imu_us {
            Some(last) if now_us <= last => return Err(EstimatorError::Step),
            Some(last) => ((now_us - last) as f32 * 1e-6).min(self.cfg.max_imu_gap_s),
            None => self.cfg.imu_period_s,
        };
        self.last_imu_us = Some(now_us);
        self.eskf.predict(imu, dt_s)?;
        for fix in fixes {
            self.push_fix(fix);
        }
        for (_, at) in self.pending.iter_mut().filter(|(_, at)| *at == UNSTAMPED) {
            *at = now_us;
        }
        if let Some((mut part, at)) = self.pending.pop_front() {
            part.age_s += (now_us - at) as f32 * 1e-6;
            let before = self.eskf.counters().pos_fused;
            // A refused fix is counted in the estimator's counters.
            let _ = self.eskf.fuse(&part);
            if self.eskf.counters().pos_fused != before {
                self.last_pos_us = Some(now_us);
            }
        }
        self.mode = self.decide(now_us);
        Ok(self.mode)
    }

    fn decide(&mut self, now_us: u64) -> NavMode {
        if self.eskf.mode() == Mode::Aligning {
            return NavMode::Aligning;
        }
        // Aligned on a position fix: that one counts as fused.
        self.last_pos_us.get_or_insert(now_us);
        let sigma_ok = self.eskf.position_sigma_m() <= self.cfg.max_position_sigma_m;
        if sigma_ok {
            self.over_since_us = None;
        } else if self.over_since_us.is_none() {
            self.over_since_us = Some(now_us);
        }
        let since = |t: u64| now_us.saturating_sub(t) as f32 * 1e-6;
        let sigma_bad = self.over_since_us.is_some_and(|t| since(t) >= self.cfg.sigma_grace_s);
        let stale = self
            .last_pos_us
            .is_none_or(|t| since(t) >= self.cfg.dead_reckoning_limit_s);
        if sigma_bad || stale {
            if self.failsafe_from.is_none() {
                if let Ok(e) = self.eskf.estimate() {
                    self.failsafe_from = Some((e.pos_ned_m, e.euler()[2], now_us));
                    self.entries = self.entries.wrapping_add(1);
                }
            }
            NavMode::Failsafe
        } else {
            self.failsafe_from = None;
            NavMode::Navigating
        }
    }

    /// The settings.
    pub fn config(&self) -> &NavConfig {
        &self.cfg
    }

    /// The mode of the last step.
    pub fn mode(&self) -> NavMode {
        self.mode
    }

    /// The estimate the controllers fly on (`None` while aligning).
    pub fn estimate(&self) -> Option<StateEstimate<f32>> {
        let est = self.eskf.estimate().ok();
        #[cfg(feature = "truth-state")]
        if est.is_some() && self.truth.is_some() {
            return self.truth;
        }
        est
    }

    /// Flies `truth` (a simulator's true state, NED about the origin)
    /// instead of the estimate from now on, once the estimator has aligned
    /// (the same start as a flight on the estimate): the controller alone,
    /// as a peer given perfect state is measured. The estimator keeps
    /// running, and its alignment and failsafe still decide the mode.
    /// `None` goes back to the estimate. Host builds only (`truth-state`):
    /// no image has it.
    #[cfg(feature = "truth-state")]
    pub fn set_truth(&mut self, truth: Option<StateEstimate<f32>>) {
        self.truth = truth;
    }

    /// The setpoint to fly at `now_us`: the mission's `sp`, or in the
    /// failsafe the hold-and-descend from where it began.
    pub fn setpoint(&self, now_us: u64, sp: &Setpoint<f32>) -> Setpoint<f32> {
        match (self.mode, self.failsafe_from) {
            (NavMode::Failsafe, Some((pos, yaw, t0))) => {
                let t = now_us.saturating_sub(t0) as f32 * 1e-6;
                let down = self.cfg.descent_mps;
                let mut s = Setpoint::hold(pos + Vector3::new(0.0, 0.0, down * t), yaw);
                s.vel_ned_mps = Vector3::new(0.0, 0.0, down);
                s
            }
            _ => *sp,
        }
    }

    /// Hands `ctrl` the preview of `sp` extrapolated along its own
    /// derivatives (the failsafe's reference, previewed as it will be).
    pub fn preview_along<C: Controller<f32> + ?Sized>(ctrl: &mut C, sp: &Setpoint<f32>) {
        if let Some((n, h)) = ctrl.preview_request() {
            for k in 1..=n {
                // A rejected point only means the controller extrapolates itself.
                let _ = ctrl.set_preview(k, &sp.extrapolate((k as f64 * h) as f32));
            }
        }
    }

    /// The estimator (covariance, biases, counters).
    pub fn estimator(&self) -> &Eskf<HISTORY> {
        &self.eskf
    }

    /// The estimator's counters.
    pub fn counters(&self) -> EskfCounters {
        self.eskf.counters()
    }

    /// Queues a fix that arrived between steps, for the next step (whose
    /// time its age counts from); split into parts as [`Navigator::step`]
    /// does. `false` if (a part of) it was dropped, the queue being full.
    pub fn push_fix(&mut self, fix: &Fix) -> bool {
        let mut all = true;
        for part in parts_of(fix).into_iter().flatten() {
            if self.pending.push_back((part, UNSTAMPED)).is_err() {
                self.dropped = self.dropped.wrapping_add(1);
                all = false;
            }
        }
        all
    }

    /// Fix parts dropped because more arrived than one a step drains.
    pub fn fixes_dropped(&self) -> u32 {
        self.dropped
    }

    /// Times the failsafe began since start.
    pub fn failsafe_entries(&self) -> u32 {
        self.entries
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_settings_are_valid() {
        assert_eq!(NavConfig::default().check(), Ok(()));
        assert!(Navigator::new(NavConfig::default()).is_ok());
    }

    #[test]
    fn bad_settings_are_named() {
        let cfg = NavConfig {
            dead_reckoning_limit_s: f32::NAN,
            ..NavConfig::default()
        };
        assert_eq!(
            Navigator::new(cfg).err(),
            Some(EstimatorError::Config("dead_reckoning_limit_s"))
        );
    }

    #[test]
    fn fixes_are_split_into_parts_of_at_most_three_updates() {
        let gps = Fix {
            pos_ned_m: Some(Vector3::zeros()),
            vel_ned_mps: Some(Vector3::zeros()),
            yaw_rad: Some(0.1),
            alt_m: Some(1.0),
            ..Fix::EMPTY
        };
        let parts = parts_of(&gps);
        let n: heapless::Vec<usize, 3> = parts.iter().flatten().map(updates_of).collect();
        assert_eq!(n.as_slice(), &[3, 3, 2]);
        // Every measurement lands in exactly one part.
        let p = |f: &Fix| f.pos_ned_m.is_some();
        assert_eq!(parts.iter().flatten().filter(|f| p(f)).count(), 1);
        let mocap = Fix {
            pos_ned_m: Some(Vector3::zeros()),
            yaw_rad: Some(0.1),
            ..Fix::EMPTY
        };
        assert_eq!(parts_of(&mocap).iter().flatten().map(updates_of).sum::<usize>(), 4);
        assert_eq!(parts_of(&mocap).iter().flatten().count(), 2);
        let baro = Fix {
            alt_m: Some(1.0),
            ..Fix::EMPTY
        };
        assert_eq!(parts_of(&baro), [Some(baro), None, None]);
    }

    /// An IMU sample of a vehicle at rest, level (body FRD: gravity read as -g on z).
    fn at_rest() -> ImuSample {
        ImuSample {
            gyro_frd_radps: Vector3::zeros(),
            accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
        }
    }

    /// A fix of position and velocity, 1 m above the origin, at rest.
    fn flood_fix() -> Fix {
        Fix {
            pos_ned_m: Some(Vector3::new(0.0, 0.0, -1.0)),
            pos_sigma_m: Vector3::repeat(0.01),
            vel_ned_mps: Some(Vector3::zeros()),
            vel_sigma_mps: 0.05,
            ..Fix::EMPTY
        }
    }

    #[test]
    fn a_flood_of_fixes_is_bounded_dropped_and_counted() {
        let mut nav = Navigator::bmi088();
        let rest = at_rest();
        let fix = flood_fix();
        // Two parts a step arrive and one is fused: the queue fills, then
        // drops (it is full before the step's part leaves it).
        for k in 1..=40u64 {
            nav.step(k * 1_000, &rest, &[fix]).unwrap();
        }
        assert_eq!(nav.fixes_dropped(), 2 * 40 - 40 - (PENDING_PARTS as u32 - 1));
        assert_eq!(nav.step(40_000, &rest, &[]), Err(EstimatorError::Step));
    }

    #[cfg(feature = "truth-state")]
    #[test]
    fn a_true_state_given_is_flown_once_aligned_and_forgotten_on_reset() {
        let mut nav = Navigator::bmi088();
        let rest = at_rest();
        // A mocap's position and heading.
        let fix = Fix {
            yaw_rad: Some(0.0),
            yaw_sigma_rad: 0.01,
            vel_ned_mps: None,
            ..flood_fix()
        };
        // Somewhere else entirely, so that it cannot be the estimate.
        let truth = StateEstimate {
            pos_ned_m: Vector3::new(3.0, -2.0, -5.0),
            vel_ned_mps: Vector3::new(0.5, 0.0, 0.0),
            att: nalgebra::Vector4::new(1.0, 0.0, 0.0, 0.0),
            rates_frd_radps: Vector3::new(0.0, 0.0, 0.1),
        };
        nav.set_truth(Some(truth));
        // Aligning: nothing to fly, the truth included (the same start as a
        // flight on the estimate).
        nav.step(1_000, &rest, &[fix]).unwrap();
        assert_eq!(nav.mode(), NavMode::Aligning);
        assert_eq!(nav.estimate(), None);
        let mut t = 1_000;
        while nav.mode() == NavMode::Aligning && t < 5_000_000 {
            t += 1_000;
            let fixes = if t % 10_000 == 0 { &[fix][..] } else { &[][..] };
            nav.step(t, &rest, fixes).unwrap();
        }
        assert_eq!(nav.mode(), NavMode::Navigating, "aligned at rest within 5 s");
        assert_eq!(nav.estimate(), Some(truth));
        // Back to the estimate: the estimator's own, at the fixes' position.
        nav.set_truth(None);
        let est = nav.estimate().unwrap();
        assert!(
            (est.pos_ned_m - Vector3::new(0.0, 0.0, -1.0)).norm() < 0.05,
            "{:?}",
            est.pos_ned_m
        );
        nav.set_truth(Some(truth));
        nav.reset();
        assert_eq!(nav.truth, None);
    }
}
