//! Where a flight's controller runs, as the flight loop sees it: one call
//! per control step. [`InProcess`] calls a controller directly;
//! `crate::link::Remote` reaches one behind the wire protocol. Neither the
//! flight loop nor the link imports the other: both import this.

use fc_core::control::{Controller, Setpoint, StateEstimate};
use fc_core::QuatState;
use std::time::Instant;

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
}

/// A controller called directly in this process.
#[derive(Debug, Clone)]
pub struct InProcess<C> {
    /// The controller (read it back after a flight, e.g. the MPC's last QP).
    pub ctrl: C,
    /// Time of the last step, s.
    last_t: Option<f64>,
}

impl<C> InProcess<C> {
    /// The endpoint of `ctrl`.
    pub fn new(ctrl: C) -> Self {
        Self { ctrl, last_t: None }
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
        // After a gap in the steps (a sensor outage), as the flight loop on
        // the MCU does: the controller forgets only the step before.
        let period = self.ctrl.period_s().unwrap_or(0.0);
        if self.last_t.is_some_and(|last| t - last > 1.5 * period && period > 0.0) {
            self.ctrl.resume();
        }
        self.last_t = Some(t);
        for (k, p) in preview.iter().enumerate() {
            // The scenario defines the reference; a rejected point only
            // means the controller extrapolates instead.
            let _ = self.ctrl.set_preview(k + 1, p);
        }
        let est = StateEstimate::from_quat_state(&state.cast::<f32>());
        let t0 = Instant::now();
        let out = self.ctrl.update(&est, sp);
        let cost = t0.elapsed().as_nanos() as f64;
        // An estimate built from a finite state is always valid: on the
        // impossible error the loop holds the last command (its fallback).
        let (u, iterations, saturated) = match out {
            Ok(o) => (
                Some([o.u[0], o.u[1], o.u[2], o.u[3]]),
                o.status.iterations,
                o.status.saturated,
            ),
            Err(_) => (None, 0, false),
        };
        Ok(StepReport {
            u,
            cost,
            iterations,
            saturated,
            failsafe: false,
            counters: None,
        })
    }
}
