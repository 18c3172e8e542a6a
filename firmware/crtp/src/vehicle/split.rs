//! The vehicle split as an image splits it (the controller's task apart
//! from the link's): [`fly_step`], [`pass_step`], [`run_work`].

use super::{
    AnyController, BorrowMut, ControllerWork, CrtpShared, CycleClock, FromFc, ImuStep, Loop, Mutex, Power, Refusal,
};
use fc_core::control::Controller;
use fc_loop::LoopOf;

impl fc_loop::HoldsLoop for CrtpShared {
    fn flight_loop_mut(&mut self) -> &mut Loop {
        &mut self.lp
    }
}

/// The [`Loop`] inside a locked [`CrtpShared`], as [`fc_loop::stabilize`] locks it.
fn loop_of<M: Mutex>(v: &mut M) -> LoopOf<'_, M, CrtpShared>
where
    M::T: BorrowMut<CrtpShared>,
{
    LoopOf::new(v)
}

/// Flies `step` on the controller `ctrl` (the controller's task), the
/// vehicle `v` locked only to take the step's inputs and record its
/// result, then to pass the supervisor's gate and the mixer
/// ([`CrtpShared::imu_end`]); returns what the motors get.
pub fn fly_step<M: Mutex, C: CycleClock>(v: &mut M, ctrl: &mut AnyController<f32>, step: ImuStep, clock: &C) -> Power
where
    M::T: BorrowMut<CrtpShared>,
{
    let u = step.job.map(|s| fc_loop::stabilize(&mut loop_of(v), ctrl, &s, clock).u);
    v.lock(|v| v.borrow_mut().imu_end(&step, u))
}

/// Answers `step` without a controller: the controller's task's step while
/// its controller is lent to a re-design ([`ControllerWork::designs`]),
/// which runs only disarmed with nothing flown (a take-off is refused while
/// one is under way). The loop records the step as one the controller did
/// not fly; the motors stay off. Returns what the motors get (nothing).
pub fn pass_step<M: Mutex, C: CycleClock>(v: &mut M, step: ImuStep, clock: &C) -> Power
where
    M::T: BorrowMut<CrtpShared>,
{
    if let Some(s) = step.job {
        loop_of(v).lock(|l| l.record(&s, None, clock));
    }
    v.lock(|v| v.borrow_mut().imu_end(&step, None))
}

/// Runs `work` ([`CrtpShared::take_work`]) on the controller `ctrl`, the
/// design with the vehicle `v` unlocked; returns its result and, for the
/// simulator's write, its answer ([`CrtpShared::work_done`]).
pub fn run_work<M: Mutex>(
    v: &mut M,
    ctrl: &mut AnyController<f32>,
    work: ControllerWork,
) -> (Result<(), Refusal>, Option<FromFc>)
where
    M::T: BorrowMut<CrtpShared>,
{
    let r = match work {
        ControllerWork::Reset => {
            ctrl.reset();
            Ok(())
        }
        ControllerWork::Param { next, .. } => fc_loop::redesign(&mut loop_of(v), ctrl, next),
    };
    let answer = v.lock(|v| v.borrow_mut().work_done(&work, r));
    (r, answer)
}
