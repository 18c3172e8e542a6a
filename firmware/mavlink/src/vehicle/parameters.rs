//! The parameter micro-service: `PARAM_SET` over [`crate::params::PARAMS`]
//! and the automatic modes' [`crate::modes::NAV_PARAMS`], each answered
//! with a `PARAM_VALUE` (a refusal with the value in force and a
//! `STATUSTEXT`).

use super::{
    nav_index_of, params, set_nav, MavMessage, MavParamType, MavSeverity, MavSink, MavVehicle, Peer, Refusal,
    NAV_PARAMS, PARAMS, PARAM_SET_DATA, PARAM_VALUE_DATA,
};

/// Every parameter served: the flight loop's ([`PARAMS`]), then the
/// automatic modes' ([`NAV_PARAMS`]).
pub const PARAM_COUNT: usize = PARAMS.len() + NAV_PARAMS.len();

/// The `param_index` of the parameter named `id` (NUL-padded), in either table.
pub fn param_index_of(id: &[u8]) -> Option<usize> {
    params::index_of(id).or_else(|| nav_index_of(id).map(|k| PARAMS.len() + k))
}

/// The name of parameter `index` (of [`PARAM_COUNT`]).
pub(super) fn param_id(index: usize) -> &'static str {
    match PARAMS.get(index) {
        Some(p) => p.id,
        None => NAV_PARAMS.get(index - PARAMS.len()).map_or("?", |p| p.id),
    }
}

impl MavVehicle {
    pub(in crate::vehicle) fn on_param_set<S: MavSink>(
        &mut self,
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
        let r = match i.checked_sub(PARAMS.len()) {
            Some(k) => set_nav(self.modes.nav_mut(), k, m.param_value),
            None => self.apply(i, m.param_value),
        };
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

    /// Takes the automatic modes' parameters ([`NAV_PARAMS`]) stored in `p`
    /// (the flight parameters are loaded into the boot settings with
    /// [`fc_storage::load_settings`]); a stored value out of range is left
    /// out. The values taken and refused, or why the store could not be read.
    pub fn restore_nav(&mut self, p: &mut dyn fc_storage::Persist) -> Result<(u16, u16), fc_storage::StoreError> {
        let (mut taken, mut refused) = (0, 0);
        for k in 0..NAV_PARAMS.len() {
            if let Some(v) = p.param((PARAMS.len() + k) as u16)? {
                match set_nav(self.modes.nav_mut(), k, v) {
                    Ok(()) => taken += 1,
                    Err(_) => refused += 1,
                }
            }
        }
        Ok((taken, refused))
    }

    /// Sets parameter `index` to `value`: checked, and applied to the
    /// controller (re-designed while disarmed), the mixer and the failsafe.
    pub fn apply(&mut self, index: usize, value: f32) -> Result<(), Refusal> {
        self.flight.apply_param(index, value, !self.modes.armed())?;
        self.mixer = Some(self.flight.settings().mixer()?);
        Ok(())
    }

    pub(in crate::vehicle) fn send_param<S: MavSink>(&self, index: usize, out: &mut S) -> Result<(), S::Error> {
        let value = match (
            PARAMS.get(index),
            index.checked_sub(PARAMS.len()).and_then(|k| NAV_PARAMS.get(k)),
        ) {
            (Some(p), _) => (p.get)(self.flight.settings()),
            (None, Some(p)) => (p.get)(self.modes.nav()),
            (None, None) => return Ok(()),
        };
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
