//! The parameter micro-service: `PARAM_SET` over the flight stack's one
//! table ([`crate::params::PARAMS`], the automatic modes' included, each
//! under its MAVLink name), answered with a `PARAM_VALUE` (a refusal with
//! the value in force and a `STATUSTEXT`).

use super::{
    params, AnyController, MavMessage, MavParamType, MavSeverity, MavShared, MavSink, Peer, Refusal, PARAMS,
    PARAM_SET_DATA, PARAM_VALUE_DATA,
};

/// Every parameter served ([`PARAMS`]).
pub const PARAM_COUNT: usize = PARAMS.len();

/// The `param_index` of the parameter named `id` (NUL-padded).
pub fn param_index_of(id: &[u8]) -> Option<usize> {
    params::index_of(id)
}

/// The MAVLink name of parameter `index` (of [`PARAM_COUNT`]).
pub(super) fn param_id(index: usize) -> &'static str {
    PARAMS.get(index).map_or("?", |p| p.mavlink_name())
}

impl MavShared {
    pub(in crate::vehicle) fn on_param_set<S: MavSink>(
        &mut self,
        ctrl: &mut AnyController<f32>,
        m: &PARAM_SET_DATA,
        out: &mut S,
    ) -> Result<(), S::Error> {
        let Some(i) = param_index_of(&m.param_id[..]) else {
            self.counters.params_refused = self.counters.params_refused.wrapping_add(1);
            return self.status(
                out,
                MavSeverity::MAV_SEVERITY_WARNING,
                &m.param_id[..],
                Refusal::Unknown,
            );
        };
        let r = self.apply(ctrl, i, m.param_value);
        if let Err(why) = r {
            self.counters.params_refused = self.counters.params_refused.wrapping_add(1);
            let id = param_id(i);
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_WARNING,
                format_args!("{id}={} refused: {why}", params::Num(m.param_value)),
            )?;
        } else if let Some(Err(e)) = out.storage().map(|st| st.set_param(i as u16, m.param_value)) {
            // Taken for this flight, but not kept: say so.
            let id = param_id(i);
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_ERROR,
                format_args!("{id} not stored: {e}"),
            )?;
        }
        // The value in force, changed or not, as the protocol asks.
        self.send_param(i, out)
    }

    /// Sets parameter `index` to `value`: checked, and applied to the
    /// controller `ctrl` (re-designed only while the motors are stopped,
    /// [`fc_loop::Loop::write_param`]), the mixer and the failsafe.
    pub fn apply(&mut self, ctrl: &mut AnyController<f32>, index: usize, value: f32) -> Result<(), Refusal> {
        // The loop's mixer follows its settings.
        let motors_turn = self.motors_turn();
        fc_loop::apply_param(&mut self.lp, ctrl, index, value, motors_turn)
    }

    pub(in crate::vehicle) fn send_param<S: MavSink>(&self, index: usize, out: &mut S) -> Result<(), S::Error> {
        let Some(p) = PARAMS.get(index) else {
            return Ok(());
        };
        let value = (p.get)(self.lp.settings());
        out.send(
            Peer::GroundStation,
            &MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
                param_value: value,
                param_count: PARAM_COUNT as u16,
                param_index: index as u16,
                param_id: param_id(index).into(),
                param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
            }),
        )
    }
}
