//! The vehicle's side of the client commander ([`fc_loop::client`]): the
//! ports' decoded commands handed to it, its refusals said on the console,
//! and the controller's reset it asks for queued for the controller's side.
//! What a command may do is the flight stack's to decide.

use super::{CommandRefusal, ControllerWork, CrtpShared, Segment, Setpoint, StreamVelocity, Takeover, WorkState};

impl CrtpShared {
    /// Flies `sp`, a client's streamed set-point (its horizontal velocity
    /// in `frame`), from now; `false`
    /// (refused) while disarmed (not said: a client streams at its rate),
    /// or when control cannot be taken ([`fc_loop::client::ClientCommander::stream`]).
    pub(in crate::vehicle) fn stream(&mut self, sp: Setpoint<f32>, frame: StreamVelocity) -> bool {
        let r = self.client.stream(sp, frame, self.now_us, self.busy());
        self.took(r, false)
    }

    /// Flies the planner's segment `seg` (`landing`: the motors stop on the
    /// ground at its end); `false` (refused, and said) when control cannot
    /// be taken ([`fc_loop::client::ClientCommander::plan`]).
    pub(in crate::vehicle) fn plan(&mut self, seg: Segment, landing: bool) -> bool {
        let r = self.client.plan(seg, landing, self.busy());
        self.took(r, true)
    }

    /// Flies uploaded trajectory `id` with `options` (a relative start from
    /// `here`, the reference flown); `false` (refused, and said) when it
    /// cannot ([`fc_loop::client::ClientCommander::start_trajectory`]).
    pub(in crate::vehicle) fn start_trajectory(
        &mut self,
        id: u8,
        options: fc_loop::trajectory::StartOptions,
        here: &super::Reference,
    ) -> bool {
        let r = self
            .client
            .start_trajectory(id, options, here, self.now_us, self.busy());
        self.took(r, true)
    }

    /// What a command's answer `r` asks of the vehicle: the controller's
    /// reset queued ([`ControllerWork::Reset`]), or its refusal said (a
    /// disarmed one only if `say_disarmed`).
    fn took(&mut self, r: Result<Takeover, CommandRefusal>, say_disarmed: bool) -> bool {
        match r {
            Ok(Takeover::Reset) => {
                self.work = WorkState::Queued(ControllerWork::Reset);
                true
            }
            Ok(Takeover::Continue) => true,
            Err(CommandRefusal::NotArmed) if !say_disarmed => false,
            Err(why) => {
                self.say(format_args!("{why}"));
                false
            }
        }
    }
}
