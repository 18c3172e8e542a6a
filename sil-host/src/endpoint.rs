//! Where a flight's controller runs, as the flight loop sees it: one call
//! per control step. [`InProcess`] calls a controller directly;
//! `crate::link::Remote` reaches one behind the wire protocol. Neither the
//! flight loop nor the link imports the other: both import this.

use crate::sensors::Readings;
use fc_core::control::{Controller, Setpoint, StateEstimate};
use fc_core::estimate::{EskfCounters, ERR};
use fc_core::QuatState;
use fc_loop::nav::{NavConfig, NavMode, Navigator};
use nalgebra::{SMatrix, Vector3};
use std::time::Instant;

/// What the on-board estimator reported at one step (sensor flights).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavReport {
    /// Aligning, navigating or in its failsafe.
    pub mode: NavMode,
    /// The estimate the controller flew on (`None` while aligning).
    pub estimate: Option<StateEstimate<f32>>,
    /// Gyro (rad/s) and accelerometer (m/s²) bias estimates, FRD.
    pub biases: (Vector3<f32>, Vector3<f32>),
    /// The error-state covariance `[δp δv δθ δb_g δb_a]` (in-process only).
    pub covariance: Option<SMatrix<f32, ERR, ERR>>,
    /// Its diagonal's square roots (NaN where the endpoint does not report them).
    pub sigmas: [f32; ERR],
    /// What the estimator refused or repaired so far.
    pub counters: EskfCounters,
    /// Failsafe episodes so far.
    pub failsafe_entries: u32,
}

/// What one control step gives back, wherever the controller ran.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepReport {
    /// Inputs `[U1 N, U2 N, U3 N, U4 N·m]` to apply until the next step;
    /// `None`: the controller gave none (the flight holds the last ones).
    pub u: Option<[f32; 4]>,
    /// Time the controller took: ns on the host, cycles (instructions
    /// under QEMU) as the flight controller reports them.
    pub cost: f64,
    /// QP iterations this step (0 for explicit laws).
    pub iterations: u16,
    /// The unconstrained law was clamped into the input box (in-process only).
    pub saturated: bool,
    /// The flight controller answered from its failsafe (remote only).
    pub failsafe: bool,
    /// The flight controller's frame and error counters (remote only).
    pub counters: Option<fc_proto::Counters>,
    /// The estimator's report (sensor flights only).
    pub nav: Option<NavReport>,
}

/// Where a flight's controller runs: called once per control step by the
/// flight loop, which knows nothing else about it.
pub trait Endpoint {
    /// The controller's execution period, s (`None`: the flight's control rate).
    fn period_s(&self) -> Option<f64>;
    /// The reference preview it wants: `(points, spacing s)`.
    fn preview(&self) -> Option<(usize, f64)>;
    /// The a-priori cap on iterations per step (0: none), for the record.
    fn iteration_bound(&self) -> u32 {
        0
    }
    /// One control step at time `t` (s): the state it sees (quaternion form,
    /// NED, f64 as measured), the setpoint and the preview points.
    fn step(
        &mut self,
        t: f64,
        state: &QuatState<f64>,
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
    ) -> anyhow::Result<StepReport>;

    /// One IMU step of a sensor flight at time `t` (s): the IMU sample and
    /// the fixes that arrived, the setpoint and, when `control` (the
    /// controller is due: the flight loop's [`fc_loop::schedule::Schedule`]),
    /// the preview points. The endpoint estimates the state itself at every
    /// step. In this process the controller runs when `control`; a flight
    /// controller over the wire decides by its own schedule, on the same
    /// grid. The report's output and iterations are the controller's only
    /// when `control` (its cost is the whole step's, estimator included).
    fn step_sensed(
        &mut self,
        t: f64,
        readings: &Readings,
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
        control: bool,
    ) -> anyhow::Result<StepReport> {
        let _ = (t, readings, sp, preview, control);
        anyhow::bail!("this endpoint flies the true state only; use --estimator truth")
    }
}

/// A controller called directly in this process.
#[derive(Debug, Clone)]
pub struct InProcess<C> {
    /// The controller (read it back after a flight, e.g. the MPC's last QP).
    pub ctrl: C,
    /// Time of the last step, s.
    last_t: Option<f64>,
    /// The on-board estimator of sensor flights (made at the first sensed step).
    nav: Option<Navigator>,
}

/// A step in which the controller gave nothing.
const NO_OUTPUT: StepReport = StepReport {
    u: None,
    cost: 0.0,
    iterations: 0,
    saturated: false,
    failsafe: false,
    counters: None,
    nav: None,
};

impl<C> InProcess<C> {
    /// The endpoint of `ctrl`.
    pub fn new(ctrl: C) -> Self {
        Self {
            ctrl,
            last_t: None,
            nav: None,
        }
    }
}

impl<C: Controller<f32>> InProcess<C> {
    /// Tells the controller the time since its last step, or resumes it
    /// after a gap (as the flight loop on the MCU does: the controller
    /// forgets only the step before), and hands it the preview.
    fn prepare(&mut self, t: f64, preview: &[Setpoint<f32>]) {
        let period = self.ctrl.period_s().unwrap_or(0.0);
        if let Some(last) = self.last_t {
            // In µs, as the flight controller over the wire measures it.
            let dt_us = ((t * 1e6).round() as u64).saturating_sub((last * 1e6).round() as u64);
            fc_core::control::tell_interval(&mut self.ctrl, dt_us, period);
        }
        self.last_t = Some(t);
        for (k, p) in preview.iter().enumerate() {
            // The scenario defines the reference; a rejected point only
            // means the controller extrapolates instead.
            let _ = self.ctrl.set_preview(k + 1, p);
        }
    }

    /// The controller's step on `est`, timed.
    fn control(&mut self, est: &StateEstimate<f32>, sp: &Setpoint<f32>) -> StepReport {
        let t0 = Instant::now();
        let out = self.ctrl.update(est, sp);
        let cost = t0.elapsed().as_nanos() as f64;
        // A valid estimate always gives an output: on the impossible error
        // the loop holds the last command (its fallback).
        let (u, iterations, saturated) = match out {
            Ok(o) => (
                Some([o.u[0], o.u[1], o.u[2], o.u[3]]),
                o.status.iterations,
                o.status.saturated,
            ),
            Err(_) => (None, 0, false),
        };
        StepReport {
            u,
            cost,
            iterations,
            saturated,
            failsafe: false,
            counters: None,
            nav: None,
        }
    }
}

impl<C: Controller<f32>> Endpoint for InProcess<C> {
    fn period_s(&self) -> Option<f64> {
        self.ctrl.period_s()
    }
    fn preview(&self) -> Option<(usize, f64)> {
        self.ctrl.preview_request()
    }
    fn iteration_bound(&self) -> u32 {
        self.ctrl.iteration_bound()
    }
    fn step(
        &mut self,
        t: f64,
        state: &QuatState<f64>,
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
    ) -> anyhow::Result<StepReport> {
        self.prepare(t, preview);
        let est = StateEstimate::from_quat_state(&state.cast::<f32>());
        Ok(self.control(&est, sp))
    }

    fn step_sensed(
        &mut self,
        t: f64,
        readings: &Readings,
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
        control: bool,
    ) -> anyhow::Result<StepReport> {
        // The fixes' ages as the flight controller gets them over the wire
        // (µs), so that both compute with the same numbers.
        let fixes: Vec<_> = readings
            .fixes
            .iter()
            .map(|f| fc_loop::fix_from_wire(&fc_loop::fix_to_wire(f)))
            .collect();
        let nav = match self.nav.as_mut() {
            Some(n) => n,
            None => self
                .nav
                .insert(Navigator::new(NavConfig::default()).map_err(|e| anyhow::anyhow!("{e}"))?),
        };
        let now_us = (t * 1e6).round() as u64;
        let t0 = Instant::now();
        let mode = nav
            .step(now_us, &readings.imu, &fixes)
            .map_err(|e| anyhow::anyhow!("estimator step at t = {t:.3} s: {e}"))?;
        let est = nav.estimate();
        let nav_cost = t0.elapsed().as_nanos() as f64;
        let fly_sp = nav.setpoint(now_us, sp);
        let report = NavReport {
            mode,
            estimate: est,
            biases: nav.estimator().biases(),
            covariance: Some(*nav.estimator().covariance()),
            sigmas: nav.estimator().sigmas().into(),
            counters: nav.counters(),
            failsafe_entries: nav.failsafe_entries(),
        };
        let mut step = match (mode, est) {
            (NavMode::Navigating, Some(est)) if control => {
                self.prepare(t, preview);
                self.control(&est, &fly_sp)
            }
            (NavMode::Failsafe, Some(est)) if control => {
                self.prepare(t, &[]);
                Navigator::preview_along(&mut self.ctrl, &fly_sp);
                let mut r = self.control(&est, &fly_sp);
                r.failsafe = true;
                r
            }
            // Aligning: no output; the flight holds its hover command (the
            // vehicle is at rest). Between the controller's runs: nothing new.
            _ => NO_OUTPUT,
        };
        step.cost += nav_cost;
        step.nav = Some(report);
        Ok(step)
    }
}
