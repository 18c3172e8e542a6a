//! Work for the controller's task ([`Job`]): a step to fly, a design to
//! run; how an image's tasks run it ([`run_job`]) and install its result.

use crate::{
    param_answer, params, AnyController, ControlError, ControlOutput, ControllerSpec, CycleClock, Exclusive, Loop,
    Mutex, Navigator, Outbox, PdEuler, PdEulerGains, ReferenceMode, Setpoint, StateEstimate, VehicleParams,
    FALLBACK_CONTROLLER,
};
use fc_core::control::Controller;

/// Work for the controller's task: everything that needs the controller.
#[derive(Debug, Clone, Copy)]
pub enum Job {
    /// A sensor or IMU step: fly it if `control` says so, then answer it.
    Step(Step),
    /// Design this controller in place of the running one (`Select`).
    Select(ControllerSpec),
    /// Write a parameter (`ParamSet`); a re-design only while the motors
    /// are stopped ([`Loop::write_param`]).
    Param {
        /// Index in [`params::PARAMS`].
        index: u16,
        /// Its new value.
        value: f32,
        /// The motors turn: our protocol's session has had a step.
        motors_turn: bool,
    },
}

/// A step the estimator (or a state frame) has taken: what its answer needs.
#[derive(Debug, Clone, Copy)]
pub struct Step {
    /// The frame's sequence number.
    pub seq: u32,
    /// The cycle clock when the step began (`None`: it was not flown; the
    /// answer reports 0 cycles).
    pub t0: Option<u32>,
    /// The answer carries the estimator's `Nav` and `NavBias` messages.
    pub nav: bool,
    /// The controller's step, when it is due.
    pub control: Option<ControlJob>,
}

/// One controller step: its inputs, as the loop prepared them.
#[derive(Debug, Clone, Copy)]
pub struct ControlJob {
    /// Time of the step, µs, on the time base's clock.
    pub now_us: u64,
    /// The state to fly from (NED, body FRD).
    pub est: StateEstimate<f32>,
    /// The set-point to fly to.
    pub sp: Setpoint<f32>,
    /// After a gap or the failsafe: the controller forgets the step before.
    pub resume: bool,
    /// The estimator's failsafe flies `sp`: the preview follows it.
    pub preview_along: bool,
    /// Time since the controller's last step, µs (none before the first).
    pub interval_us: Option<u64>,
    /// The controller's period, s.
    pub period_s: f64,
}

impl ControlJob {
    /// Runs the step on `ctrl`: resume, preview, the measured interval,
    /// then the update.
    pub fn fly(&self, ctrl: &mut AnyController<f32>) -> Result<ControlOutput<f32>, ControlError> {
        if self.resume {
            ctrl.resume();
        }
        if self.preview_along {
            Navigator::preview_along(ctrl, &self.sp);
        }
        if let Some(dt) = self.interval_us {
            fc_core::control::tell_interval(ctrl, dt, self.period_s);
        }
        ctrl.update(&self.est, &self.sp)
    }
}

/// What one flown step gives the motors' side: the inputs and what the
/// step cost. No wire message in between: a protocol adapter mixes `u`
/// for its motors; our own protocol answers it as `Actuator` and
/// `Telemetry` ([`Loop::answers`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Actuation {
    /// The inputs to apply `[U1 N, U2 N, U3 N, U4 N·m]`: the controller's,
    /// or the last ones held when it was not due or failed (hover thrust
    /// while the estimator aligns).
    pub u: [f32; 4],
    /// The loop is in a failsafe (its sensor timer, or the estimator's).
    pub failsafe: bool,
    /// Cycles from the step's start to its end (0: not flown).
    pub cycles: u32,
    /// The MPC's QP iterations this step (0 for the other controllers).
    pub qp_iterations: u16,
}

/// A front end's vehicle state that holds its flight [`Loop`] (all but the
/// controller): what [`LoopOf`] locks the loop through.
pub trait HoldsLoop {
    /// The flight loop.
    fn flight_loop_mut(&mut self) -> &mut Loop;
}

/// The [`Loop`] inside a front end's locked vehicle state `V` (the
/// [`Mutex`] `M` holds a `V`): what [`stabilize`] and [`redesign`] lock
/// when the vehicle, not the bare loop, is the resource an image shares.
pub struct LoopOf<'a, M, V: ?Sized>(&'a mut M, core::marker::PhantomData<fn() -> *const V>);

impl<'a, M, V: ?Sized> LoopOf<'a, M, V> {
    /// The loop inside `m`.
    pub fn new(m: &'a mut M) -> Self {
        Self(m, core::marker::PhantomData)
    }
}

impl<M: Mutex, V: HoldsLoop + ?Sized> Mutex for LoopOf<'_, M, V>
where
    M::T: core::borrow::BorrowMut<V>,
{
    type T = Loop;
    fn lock<R>(&mut self, f: impl FnOnce(&mut Loop) -> R) -> R {
        self.0
            .lock(|v| f(core::borrow::BorrowMut::<V>::borrow_mut(v).flight_loop_mut()))
    }
}

/// The controller's half of one stabilizer step (the estimator's half,
/// [`Loop::imu_job`], made `step`: the estimate, the commander's set-point,
/// whether the controller is due): the previews, the controller's update,
/// its result recorded in the loop `lp` (locked only for those moments);
/// returns the controller's inputs. The supervisor's gate and the mixer
/// follow ([`Loop::power`]).
pub fn stabilize<M: Mutex<T = Loop>, C: CycleClock>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    step: &Step,
    clock: &C,
) -> Actuation {
    let result = step.control.map(|c| {
        lp.lock(|l| l.apply_previews(ctrl));
        c.fly(ctrl)
    });
    lp.lock(|l| l.record(step, result, clock))
}

/// A design's inputs, copied out of the [`Loop`] so that the design (which
/// takes milliseconds to tens of them) runs without it.
#[derive(Debug, Clone, Copy)]
pub struct Design {
    /// The vehicle designed for.
    pub vehicle: VehicleParams<f32>,
    /// Gains and weights.
    pub tuning: fc_core::control::Tuning,
    /// The loop's control period, s (PD, LQR).
    pub control_period_s: f64,
    /// The controller flying now: designed again if the new one fails.
    pub running: ControllerSpec,
}

impl Design {
    /// Designs `spec` into `ctrl`. On failure the running controller is
    /// designed again (the slot no longer holds it), or the fallback PD if
    /// even that fails. Returns the result and what flies afterwards.
    pub fn run(
        &self,
        ctrl: &mut AnyController<f32>,
        spec: ControllerSpec,
    ) -> (Result<(), ControlError>, ControllerSpec) {
        let build = |s: ControllerSpec, c: &mut AnyController<f32>| {
            s.build_in(c, self.vehicle, self.control_period_s, None, &self.tuning)
        };
        match build(spec, ctrl) {
            Ok(()) => (Ok(()), spec),
            Err(e) if build(self.running, ctrl).is_ok() => (Err(e), self.running),
            Err(e) => {
                // PD designs cannot fail: nothing to check.
                let _ = build(FALLBACK_CONTROLLER, ctrl);
                (Err(e), FALLBACK_CONTROLLER)
            }
        }
    }
}

/// Runs `job` on the controller's side: the controller `ctrl`, the shared
/// loop `lp` locked only to read the step's previews and to record its
/// result, the answers to `out`. [`FlightLoop`](crate::FlightLoop) calls it directly; an image
/// whose controller runs in its own task calls it there.
pub fn run_job<M: Mutex<T = Loop>, O: Outbox, C: CycleClock>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    job: Job,
    out: &mut O,
    clock: &C,
) -> Result<(), O::Error> {
    match job {
        Job::Step(step) => {
            let a = stabilize(lp, ctrl, &step, clock);
            let answers = lp.lock(|l| l.answers(&step, &a));
            answers.iter().try_for_each(|m| out.send(m))
        }
        Job::Select(spec) => {
            if select(lp, ctrl, spec).is_err() {
                lp.lock(|l| l.counters.invalid_values = l.counters.invalid_values.wrapping_add(1));
            }
            Ok(())
        }
        Job::Param {
            index,
            value,
            motors_turn,
        } => {
            let r = lp
                .lock(|l| l.write_param(usize::from(index), value, motors_turn))
                .and_then(|next| next.map_or(Ok(()), |next| redesign(lp, ctrl, next)));
            let answer = lp.lock(|l| {
                if r.is_err() {
                    l.counters.invalid_values = l.counters.invalid_values.wrapping_add(1);
                }
                param_answer(&l.settings, index, r.err())
            });
            out.send(&answer)
        }
    }
}

/// Designs `spec` on `ctrl` in place of the running controller, the loop
/// unlocked while it runs; on failure the running one is designed again, or
/// the fallback PD if even that fails ([`Design::run`]), and the error is
/// returned. The loop records what flies ([`Loop::installed`]).
pub fn install<M: Mutex<T = Loop>>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    spec: ControllerSpec,
) -> Result<(), ControlError> {
    let (r, flying) = lp.lock(|l| l.design()).run(ctrl, spec);
    lp.lock(|l| l.installed(spec, r.is_ok(), flying, ctrl));
    r
}

/// Selects `spec` (as a `Select` does): [`install`], counted as a
/// selection when it was built; on failure the running controller keeps
/// flying and the error is returned.
pub fn select<M: Mutex<T = Loop>>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    spec: ControllerSpec,
) -> Result<(), ControlError> {
    install(lp, ctrl, spec)?;
    lp.lock(|l| l.selections = l.selections.wrapping_add(1));
    Ok(())
}

/// Starts a protocol front end's loop `lp` with its controller `ctrl`
/// ([`FlightLoop::start_front_end`](crate::FlightLoop::start_front_end)): the settings checked, their
/// controller designed in place, the session opened (set-points may come
/// before samples), the mixer the settings give for its motors set
/// ([`Loop::mixer`]).
pub fn start_front_end(lp: &mut Loop, ctrl: &mut AnyController<f32>) -> Result<(), params::Refusal> {
    lp.settings.check()?;
    let spec = lp.settings.controller;
    install(&mut Exclusive(&mut *lp), ctrl, spec).map_err(params::Refusal::Design)?;
    lp.open_session();
    lp.mixer = Some(lp.settings.mixer()?);
    Ok(())
}

/// Sets parameter `index` ([`params::PARAMS`]) of the loop `lp` to
/// `value` ([`Loop::write_param`], then [`redesign`] on its controller
/// `ctrl` if it asks for one): the whole settings checked; a change that re-designs is
/// refused while `motors_turn` (the front end's supervisor gate, the one it
/// gives [`Loop::power`]). A refusal leaves everything as it was.
pub fn apply_param(
    lp: &mut Loop,
    ctrl: &mut AnyController<f32>,
    index: usize,
    value: f32,
    motors_turn: bool,
) -> Result<(), params::Refusal> {
    match lp.write_param(index, value, motors_turn)? {
        Some(next) => redesign(&mut Exclusive(lp), ctrl, next),
        None => Ok(()),
    }
}

/// The controller a loop flies before its first design: the tuned Euler
/// PD ([`FALLBACK_CONTROLLER`], which needs no design) for `vehicle`.
pub fn fallback_controller(vehicle: VehicleParams<f32>) -> AnyController<f32> {
    AnyController::PdEuler(PdEuler::new(vehicle, PdEulerGains::tuned(), ReferenceMode::Feedforward))
}

/// Carries out a parameter write that re-designs ([`Loop::write_param`]'s
/// `next`): the design runs on `ctrl` with the loop unlocked, and `next`
/// is put in force once it is done; a refusal leaves everything as it was.
pub fn redesign<M: Mutex<T = Loop>>(
    lp: &mut M,
    ctrl: &mut AnyController<f32>,
    next: params::Settings,
) -> Result<(), params::Refusal> {
    let (old, design) = lp.lock(|l| (l.settings, l.design()));
    let (r, flying) = Design {
        vehicle: next.vehicle,
        tuning: next.tuning,
        ..design
    }
    .run(ctrl, next.controller);
    match r {
        Ok(()) => {
            lp.lock(|l| {
                l.installed(next.controller, true, flying, ctrl);
                if next.controller != old.controller {
                    l.selections = l.selections.wrapping_add(1);
                }
                l.set_settings(next);
            });
            Ok(())
        }
        Err(e) => {
            // Back to the old settings, and their controller (it
            // was designed from them before).
            let (r_old, flying) = Design {
                running: flying,
                ..design
            }
            .run(ctrl, old.controller);
            lp.lock(|l| l.installed(old.controller, r_old.is_ok(), flying, ctrl));
            Err(params::Refusal::Design(e))
        }
    }
}
