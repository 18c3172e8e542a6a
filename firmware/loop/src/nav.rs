//! Flying from sensors: the estimator between the IMU and fix messages and
//! the controllers, its alignment, and the failsafe that trusts it only as
//! far as it deserves.
//!
//! Per control step: predict with the IMU sample, fuse the fixes that
//! arrived, then decide the mode:
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

/// Steps of estimator history for delayed fixes (256 ms at 500 Hz, 128 ms at 1 kHz).
pub const HISTORY: usize = 128;

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
}

impl Default for NavConfig {
    fn default() -> Self {
        Self {
            eskf: EskfConfig::BMI088,
            max_position_sigma_m: 1.0,
            sigma_grace_s: 0.5,
            dead_reckoning_limit_s: 5.0,
            descent_mps: 0.3,
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
        ];
        fc_core::estimate::check_positive(&fields)
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
    /// Since when the position 1σ has been over the bound, µs.
    over_since_us: Option<u64>,
    /// Where and when the failsafe began: position (NED, m), heading, µs.
    failsafe_from: Option<(Vector3<f32>, f32, u64)>,
    entries: u32,
}

impl Navigator {
    /// A navigator waiting to align. `Err` names a bad setting.
    pub fn new(cfg: NavConfig) -> Result<Self, EstimatorError> {
        cfg.check()?;
        Ok(Self {
            cfg,
            eskf: Eskf::new(cfg.eskf)?,
            mode: NavMode::Aligning,
            last_pos_us: None,
            over_since_us: None,
            failsafe_from: None,
            entries: 0,
        })
    }

    /// The default navigator (BMI088, the default failsafe), which cannot
    /// fail: its settings are valid (`tests::the_default_settings_are_valid`).
    pub fn bmi088() -> Self {
        let cfg = NavConfig::default();
        Self {
            cfg,
            eskf: Eskf::new_unchecked(cfg.eskf),
            mode: NavMode::Aligning,
            last_pos_us: None,
            over_since_us: None,
            failsafe_from: None,
            entries: 0,
        }
    }

    /// Forgets the flight (a new session is a new time line), in place.
    pub fn reset(&mut self) {
        self.eskf.reset();
        self.mode = NavMode::Aligning;
        self.last_pos_us = None;
        self.over_since_us = None;
        self.failsafe_from = None;
    }

    /// One control step at time `now_us` (µs, increasing) of `dt_s` seconds:
    /// the IMU sample and the fixes that arrived. A refused fix is counted by
    /// the estimator and changes nothing; `Err` only for a bad step length.
    pub fn step(&mut self, now_us: u64, dt_s: f32, imu: &ImuSample, fixes: &[Fix]) -> Result<NavMode, EstimatorError> {
        self.eskf.predict(imu, dt_s)?;
        for fix in fixes {
            let before = self.eskf.counters().pos_fused;
            // A refused fix is counted in the estimator's counters.
            let _ = self.eskf.fuse(fix);
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

    /// The mode of the last step.
    pub fn mode(&self) -> NavMode {
        self.mode
    }

    /// The estimate the controllers fly on (`None` while aligning).
    pub fn estimate(&self) -> Option<StateEstimate<f32>> {
        self.eskf.estimate().ok()
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
}
