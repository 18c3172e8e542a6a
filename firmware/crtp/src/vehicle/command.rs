//! The vehicle's side of the commander ([`fc_loop::commander`]): whether a
//! command the ports decoded may take control, then the commander's call.
//! The ports decode; what is allowed is decided here.

use super::{ControllerWork, CrtpShared, Priority, Segment, Setpoint, WorkState};

impl CrtpShared {
    /// Flies `sp`, a client's streamed set-point, from now; `false`
    /// (refused) while disarmed, or when control cannot be taken
    /// ([`Self::take_control`]) from anything but a stream.
    pub(in crate::vehicle) fn stream(&mut self, sp: Setpoint<f32>) -> bool {
        if !self.armed() {
            return false;
        }
        if self.commander.priority() != Priority::Streamed && !self.take_control() {
            return false;
        }
        self.commander.stream(sp, self.now_us);
        true
    }

    /// Flies the planner's segment `seg` (`landing`: the motors stop on the
    /// ground at its end); `false` (refused) when control cannot be taken.
    pub(in crate::vehicle) fn plan(&mut self, seg: Segment, landing: bool) -> bool {
        if !self.take_control() {
            return false;
        }
        self.commander.plan(seg, landing);
        true
    }

    /// Whether a command may fly: armed, no controller design under way
    /// (each refusal said). From idle, the controller's state is forgotten
    /// first (no state wound up on the ground; [`ControllerWork::Reset`]).
    pub(in crate::vehicle) fn take_control(&mut self) -> bool {
        if !self.armed() {
            self.say(format_args!("not armed"));
            return false;
        }
        if self.busy() {
            self.say(format_args!("controller design under way"));
            return false;
        }
        if self.commander.is_idle() {
            self.work = WorkState::Queued(ControllerWork::Reset);
        }
        true
    }
}
