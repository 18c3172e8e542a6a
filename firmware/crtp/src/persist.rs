//! cflib's persistent parameters (`MISC_PERSISTENT_STORE`, `_GET_STATE`,
//! `_CLEAR` on the param port's misc channel): the vehicle takes the
//! request and notes what it needs ([`PersistRequest`]); the link's owner
//! answers it with its storage, outside the vehicle's lock (a flash write
//! must not hold up the estimator's task).

use crate::log::EIO;
use crate::value::put_typed;
use crate::{CrtpSink, Packet, Port};

/// The param port's misc channel's commands (cflib's `param.py`
/// `MISC_*`; the firmware's `param_logic.c`).
pub mod misc {
    /// Set a parameter by its name.
    pub const SET_BY_NAME: u8 = 0;
    /// Store the value in force.
    pub const PERSISTENT_STORE: u8 = 3;
    /// The stored state: stored or not, the default, the stored value.
    pub const PERSISTENT_GET_STATE: u8 = 4;
    /// Forget the stored value.
    pub const PERSISTENT_CLEAR: u8 = 5;
    /// The extended type: persistent or not (protocol 11+).
    pub const GET_EXTENDED_TYPE_V2: u8 = 7;
    /// The default value (protocol 11+).
    pub const GET_DEFAULT_VALUE_V2: u8 = 8;
}

/// What a persistent-parameter request asks, with what its answer needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PersistRequest {
    /// [`misc::PERSISTENT_STORE`], [`misc::PERSISTENT_GET_STATE`] or
    /// [`misc::PERSISTENT_CLEAR`].
    pub cmd: u8,
    /// The parameter's TOC id (its index in the settings store).
    pub id: u16,
    /// Its value in force (what a store keeps).
    pub now: f32,
    /// Its default (what the state reports beside the stored value).
    pub default: f32,
    /// Its CRTP type byte (how values are written in the answer).
    pub ty: u8,
}

impl PersistRequest {
    /// Does what was asked in `out`'s storage and sends the answer:
    /// `[cmd, id, 0]` when stored or cleared; for the state `[4, id,
    /// stored?, default, (stored value)]`; `[cmd, id, EIO]` when there is no
    /// storage or it failed (the state then reads "not stored").
    pub fn answer<S: CrtpSink>(&self, out: &mut S) -> Result<(), S::Error> {
        let id = self.id.to_le_bytes();
        let mut r = Packet::new(Port::Param, 3, &[self.cmd, id[0], id[1]]).unwrap_or(Packet::NULL);
        let done = match (self.cmd, out.storage()) {
            (misc::PERSISTENT_GET_STATE, None) => Ok(None),
            (_, None) => Err(()),
            (misc::PERSISTENT_STORE, Some(st)) => st.set_param(self.id, self.now).map(|()| None).map_err(|_| ()),
            (misc::PERSISTENT_GET_STATE, Some(st)) => st.param(self.id).map_err(|_| ()),
            (_, Some(st)) => st.remove_param(self.id).map(|()| None).map_err(|_| ()),
        };
        match (self.cmd, done) {
            (_, Err(())) => {
                let _ = r.extend(&[EIO]);
            }
            (misc::PERSISTENT_GET_STATE, Ok(stored)) => {
                let _ = r.extend(&[u8::from(stored.is_some())]);
                put_typed(&mut r, self.ty, self.default);
                if let Some(v) = stored {
                    put_typed(&mut r, self.ty, v);
                }
            }
            (_, Ok(_)) => {
                let _ = r.extend(&[0]);
            }
        }
        out.send(&r)
    }
}
