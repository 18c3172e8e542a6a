//! Port param (2): the param TOC of [`fc_loop::params::PARAMS`] (each in
//! its true type, and again under its Crazyflie name where the table gives
//! one, [`fc_loop::params::CRTP_ALIASED`]) and of [`EXTRA_PARAMS`]; read,
//! write, set by name, default values, extended types, persistent storage.

use crate::persist::misc;
use crate::value::{put_typed, read_value, same_type};
use crate::vehicle::*;

/// A TOC entry under a Crazyflie name that is not one of [`PARAMS`]'
/// own entries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Extra {
    /// The [`PARAMS`] index of a parameter under its Crazyflie name
    /// ([`Param::crtp_alias`](fc_loop::params::Param::crtp_alias):
    /// `stabilizer.controller` is `CTL_ID`, `pid_attitude.*` the PD's
    /// attitude gains).
    Alias(usize),
    /// `kalman.resetEstimation`: 1 restarts the estimator (on the ground).
    ResetEstimation,
    /// `stabilizer.estimator`: 2, the Kalman filter (the only one here).
    Estimator,
    /// `commander.enHighLevel`: 1, the high-level commander is always on.
    EnHighLevel,
    /// `deck.bc*`, read-only: 1 if the deck with this bit of
    /// [`DECK_NAMES`] is reported attached ([`CrtpVehicle::report_decks`]),
    /// else 0; at boot none is. cfclient's flight tab reads them to offer
    /// height hold and command-based flight; cflib's scripts wait for a
    /// positioning deck's.
    Deck(u8),
    /// `led.bitmask`: the LED override a swarm's scripts write (cflib's
    /// `sbs_swarm.py` writes 255, then 0; Crazyswarm's 128 turns the LEDs
    /// off). Stored and read back as written; the SIL and the images in
    /// QEMU have no LEDs, so nothing lights.
    LedBitmask,
    /// `ring.effect`, persistent as on a Crazyflie: the LED ring deck's
    /// effect (its default 6, the Crazyflie's), kept, read back and
    /// stored by cflib's persistent parameters (`persistent_params.py`
    /// stores it). No LED ring is attached here (`deck.bcLedRing` reads
    /// 0), so nothing lights.
    RingEffect,
}

/// `ring.effect` at boot: the Crazyflie's `LEDRING_DEFAULT_EFFECT`.
pub const RING_EFFECT_DEFAULT: u8 = 6;

impl Extra {
    /// The one value a fixed choice has (`None`: an alias, a command, a
    /// deck's flag, the LED override or the ring's effect, which read
    /// their own).
    pub const fn fixed(self) -> Option<f32> {
        match self {
            Extra::Estimator => Some(2.0),
            Extra::EnHighLevel => Some(1.0),
            Extra::Alias(_) | Extra::ResetEstimation | Extra::Deck(_) | Extra::LedBitmask | Extra::RingEffect => None,
        }
    }
}

/// The Crazyflie-named entries that are not the flight stack's
/// parameters, last in the param TOC: a command, the fixed choices of a
/// Crazyflie (the Kalman estimator, the high-level commander) and the
/// decks, none attached, the LED override and the LED ring's effect (no
/// LEDs here).
pub const EXTRA_PARAMS: [(&str, &str, u8, Extra); 13] = [
    ("kalman", "resetEstimation", param_types::U8, Extra::ResetEstimation),
    ("stabilizer", "estimator", param_types::U8, Extra::Estimator),
    ("commander", "enHighLevel", param_types::U8, Extra::EnHighLevel),
    ("deck", DECK_NAMES[0], DECK, Extra::Deck(0)),
    ("deck", DECK_NAMES[1], DECK, Extra::Deck(1)),
    ("deck", DECK_NAMES[2], DECK, Extra::Deck(2)),
    ("deck", DECK_NAMES[3], DECK, Extra::Deck(3)),
    ("deck", DECK_NAMES[4], DECK, Extra::Deck(4)),
    ("deck", DECK_NAMES[5], DECK, Extra::Deck(5)),
    ("deck", DECK_NAMES[6], DECK, Extra::Deck(6)),
    ("deck", DECK_NAMES[7], DECK, Extra::Deck(7)),
    ("led", "bitmask", param_types::U8, Extra::LedBitmask),
    // Extended (persistent), as the firmware's `PARAM_UINT8 | PARAM_PERSISTENT`.
    (
        "ring",
        "effect",
        param_types::U8 | param_types::EXTENDED,
        Extra::RingEffect,
    ),
];

/// Whether parameter `id` persists (cflib's `persistent_store` keeps it,
/// under its TOC id): the flight parameters and `ring.effect`.
pub fn persistent(id: usize) -> bool {
    id < CRTP_PARAMS || matches!(param_entry(id), Some((_, _, Some(Extra::RingEffect))))
}

/// The decks' flags in the param TOC (group `deck`), bit `i` of a deck
/// mask is `DECK_NAMES[i]`: the Flow decks, the Z-rangers, Lighthouse, the
/// Loco deck (two names) and the LED ring.
pub const DECK_NAMES: [&str; 8] = [
    "bcFlow",
    "bcFlow2",
    "bcZRanger",
    "bcZRanger2",
    "bcLighthouse4",
    "bcLoco",
    "bcDWM1000",
    "bcLedRing",
];

/// A deck's attached flag: `PARAM_UINT8 | PARAM_RONLY`, as the firmware's deck drivers declare it.
const DECK: u8 = param_types::U8 | param_types::RONLY;

/// Entries in the param TOC: the flight stack's parameters CRTP serves
/// ([`CRTP_PARAMS`], the same ids as their [`PARAMS`] indexes), those of
/// them with a Crazyflie name under it ([`CRTP_ALIASES`]), then
/// [`EXTRA_PARAMS`].
pub const PARAM_COUNT: usize = CRTP_PARAMS + CRTP_ALIASES + EXTRA_PARAMS.len();

/// The CRC of the parameters' table of contents as [`toc_item`] serves it
/// ([`toc::crc_of_items`]).
pub(in crate::vehicle) fn toc_crc() -> u32 {
    toc::crc_of_items(PARAM_COUNT as u16, toc_item)
}

/// The `GET_ITEM_V2` answer for parameter `id`.
fn toc_item(id: u16) -> Packet {
    match param_entry(usize::from(id)) {
        Some((n, t, _)) => toc::item_packet(Port::Param, id, t, &n).unwrap_or(Packet::NULL),
        None => toc::no_item_packet(Port::Param),
    }
}

/// Group and name of param `id`, its type byte, and what it is.
pub fn param_entry(id: usize) -> Option<(Name<'static>, u8, Option<Extra>)> {
    if let Some((group, name, p)) = crtp_params()
        .get(id)
        .and_then(|p| p.crtp_name().map(|(g, n)| (g, n, p)))
    {
        return Some((
            Name {
                group,
                name,
                lower_group: true,
            },
            // Its true type; every flight parameter persists, as the
            // Crazyflie's tuning does.
            toc_type(p.ty) | param_types::EXTENDED,
            None,
        ));
    }
    let k = id.checked_sub(CRTP_PARAMS)?;
    if let Some(&i) = CRTP_ALIASED.get(k) {
        let (group, name) = PARAMS[i].crtp_alias()?;
        return Some((
            Name {
                group,
                name,
                lower_group: false,
            },
            // Its true type; the Crazyflie's own entry persists, not this one.
            toc_type(PARAMS[i].ty),
            Some(Extra::Alias(i)),
        ));
    }
    let &(group, name, t, extra) = EXTRA_PARAMS.get(k - CRTP_ALIASES)?;
    Some((
        Name {
            group,
            name,
            lower_group: false,
        },
        t,
        Some(extra),
    ))
}

/// The id of the parameter named `group.name` (the group compared without
/// case, [`Name::is`]), as a set by name finds it: the first entry that has
/// that name. Every entry is tried, under the link's lock of the vehicle,
/// so each one's length is compared before its name is made.
pub fn param_named(group: &[u8], name: &[u8]) -> Option<usize> {
    let len = group.len() + 1 + name.len();
    (0..PARAM_COUNT).find(|&i| may_be_named(i, len) && param_entry(i).is_some_and(|(n, _, _)| n.is(group, name)))
}

/// Whether entry `id`'s group, a separator and its name could be `len`
/// bytes, read without making its name ([`param_entry`]).
fn may_be_named(id: usize, len: usize) -> bool {
    if let Some(p) = crtp_params().get(id) {
        // `GROUP_NAME`, or `NAME` in the group `fc` ([`Param::crtp_name`]).
        return p.id.len() == len || p.id.len() + 3 == len;
    }
    let Some(k) = id.checked_sub(CRTP_PARAMS) else {
        return false;
    };
    if let Some(&i) = CRTP_ALIASED.get(k) {
        return PARAMS[i].crazyflie_alias.len() == len;
    }
    EXTRA_PARAMS
        .get(k - CRTP_ALIASES)
        .is_some_and(|(g, n, _, _)| g.len() + 1 + n.len() == len)
}

/// The param TOC's type byte of a parameter of type `ty`.
const fn toc_type(ty: ParamType) -> u8 {
    match ty {
        ParamType::F32 => param_types::FLOAT,
        ParamType::U8 => param_types::U8,
        ParamType::U16 => param_types::U16,
    }
}

/// The answer to the `MISC_SETBYNAME` request `request` (`[0, group\0,
/// name\0, type, value]`) with status `code`: `[0, group\0, name\0, code]`.
fn set_by_name_reply(request: &Packet, code: u8) -> Packet {
    let d = request.payload().get(1..).unwrap_or(&[]);
    let mut parts = d.splitn(3, |&b| b == 0);
    let names = match (parts.next(), parts.next()) {
        (Some(group), Some(name)) => (group.len() + name.len() + 2).min(d.len()),
        _ => d.len(),
    };
    let mut r = reply(Port::Param, 3, &[0]);
    let _ = r.extend(&d[..names]);
    let _ = r.extend(&[code]);
    r
}

impl CrtpShared {
    /// Parameter `id`'s value in force.
    pub(in crate::vehicle) fn param_value(&self, id: usize) -> Option<f32> {
        let s = self.lp.settings();
        let (_, _, extra) = param_entry(id)?;
        Some(match extra {
            None => (PARAMS[id].get)(s),
            Some(Extra::ResetEstimation) => 0.0,
            Some(Extra::LedBitmask) => f32::from(self.led_bitmask),
            Some(Extra::RingEffect) => f32::from(self.ring_effect),
            Some(Extra::Deck(bit)) => f32::from((self.decks >> bit) & 1),
            Some(Extra::Alias(i)) => (PARAMS[i].get)(s),
            Some(fixed) => fixed.fixed()?,
        })
    }

    /// Parameter `id`'s value at boot.
    pub(in crate::vehicle) fn param_default(&self, id: usize) -> Option<f32> {
        let (_, _, extra) = param_entry(id)?;
        Some(match extra {
            None => (PARAMS[id].get)(&self.defaults),
            Some(Extra::Alias(i)) => (PARAMS[i].get)(&self.defaults),
            Some(Extra::LedBitmask) => 0.0,
            Some(Extra::RingEffect) => f32::from(RING_EFFECT_DEFAULT),
            Some(_) => self.param_value(id)?,
        })
    }

    /// Writes parameter `id`: checked, applied (re-designs only while the
    /// motors are off; a re-design is queued for the controller's side,
    /// and `reply` answered when it is done). Refused while other
    /// controller work is under way.
    pub(in crate::vehicle) fn param_write(&mut self, id: usize, value: f32, reply: Reply) -> Result<Written, Refusal> {
        let (_, _, extra) = param_entry(id).ok_or(Refusal::Unknown)?;
        // The LED override and the ring's effect touch no flight state:
        // taken even while the controller is busy, if they are a byte.
        if let Some(led @ (Extra::LedBitmask | Extra::RingEffect)) = extra {
            if !((0.0..=255.0).contains(&value) && value == f32::from(value as u8)) {
                return Err(Refusal::Range { lo: 0.0, hi: 255.0 });
            }
            if led == Extra::LedBitmask {
                self.led_bitmask = value as u8;
            } else {
                self.ring_effect = value as u8;
            }
            return Ok(Written::Now);
        }
        if self.busy() {
            return Err(Refusal::Busy);
        }
        let index = match extra {
            None => id,
            Some(Extra::Alias(i)) => i,
            Some(Extra::ResetEstimation) if value == 0.0 => return Ok(Written::Now),
            Some(Extra::ResetEstimation) => {
                self.lp.reset_estimation(self.flying())?;
                self.heading_seen = false;
                self.say(format_args!("estimator reset"));
                return Ok(Written::Now);
            }
            // A fixed choice or a read-only flag takes its value in force
            // and refuses any other, naming it.
            Some(_) => {
                let v = self.param_value(id).ok_or(Refusal::Unknown)?;
                return if value == v {
                    Ok(Written::Now)
                } else {
                    Err(Refusal::Range { lo: v, hi: v })
                };
            }
        };
        // Checked as a whole, the mixer's settings included, before
        // anything is taken.
        match self.lp.write_param(index, value, self.flying())? {
            Some(next) => {
                self.work = WorkState::Queued(ControllerWork::Param { next, reply });
                Ok(Written::Later)
            }
            // Taken (the loop's mixer follows its settings), or in force.
            None => Ok(Written::Now),
        }
    }

    /// The answer to the parameter write `request` (by id on channel 2:
    /// the value in force; by name: its status), refused for `refused`
    /// (said on the console) or not.
    pub(in crate::vehicle) fn written_reply(&mut self, request: &Packet, refused: Option<Refusal>) -> Packet {
        let d = request.payload();
        if request.channel() == 3 {
            return set_by_name_reply(request, if refused.is_some() { log::ENOEXEC } else { 0 });
        }
        let id = u16_at(d, 0).map_or(usize::MAX, usize::from);
        if let (Some(why), Some((name, _, _))) = (refused, param_entry(id)) {
            self.say(format_args!("{}.{}: {}", name.group, name.name, why));
        }
        let mut r = reply(Port::Param, 2, &d[..2.min(d.len())]);
        // The value in force, changed or not.
        let now = self.param_value(id).unwrap_or(f32::NAN);
        self.put_value(&mut r, id, now);
        r
    }

    pub(in crate::vehicle) fn on_param<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        let d = p.payload();
        match p.channel() {
            0 => match d.first() {
                Some(&toc::CMD_GET_INFO_V2) => {
                    if let Ok(r) = toc::info_packet(Port::Param, PARAM_COUNT as u16, self.toc_crcs.param, &[]) {
                        out.send(&r)?;
                    }
                }
                Some(&toc::CMD_GET_ITEM_V2) => {
                    let Some(id) = u16_at(d, 1) else {
                        return Ok(Err(short(p)));
                    };
                    out.send(&toc_item(id))?;
                }
                _ => return Ok(Err(unsupported(p))),
            },
            1 => {
                let Some(id) = u16_at(d, 0) else {
                    return Ok(Err(short(p)));
                };
                let mut r = reply(Port::Param, 1, &id.to_le_bytes());
                match self.param_value(usize::from(id)) {
                    Some(v) => {
                        let _ = r.extend(&[0]);
                        self.put_value(&mut r, usize::from(id), v);
                    }
                    None => {
                        let _ = r.extend(&[log::ENOENT]);
                    }
                }
                out.send(&r)?;
            }
            2 => {
                let Some(id) = u16_at(d, 0) else {
                    return Ok(Err(short(p)));
                };
                let id = usize::from(id);
                let Some((_, t, _)) = param_entry(id) else {
                    let mut r = reply(Port::Param, 2, &d[..2]);
                    let _ = r.extend(&[log::ENOENT]);
                    out.send(&r)?;
                    return Ok(Err(unsupported(p)));
                };
                if self.busy() {
                    // Not answered: the client repeats its write, and it is
                    // taken once the design under way is done.
                    return Ok(Err(CrtpError::Refused { port: p.port() }));
                }
                let refused = match read_value(t, &d[2..]) {
                    Some(v) => match self.param_write(id, v, Reply::Crtp(*p)) {
                        Ok(Written::Later) => return Ok(Ok(())),
                        Ok(Written::Now) => None,
                        Err(e) => Some(e),
                    },
                    None => Some(Refusal::NotInteger),
                };
                let r = self.written_reply(p, refused);
                out.send(&r)?;
                if refused.is_some() {
                    return Ok(Err(CrtpError::Refused { port: p.port() }));
                }
            }
            3 => return self.on_param_misc(p, out),
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    /// Appends parameter `id`'s value `v` in its type.
    pub(in crate::vehicle) fn put_value(&self, r: &mut Packet, id: usize, v: f32) {
        put_typed(r, param_entry(id).map_or(param_types::FLOAT, |(_, t, _)| t), v);
    }

    pub(in crate::vehicle) fn on_param_misc<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        if cmd == misc::SET_BY_NAME {
            return self.on_set_by_name(p, out);
        }
        let Some(id) = u16_at(d, 1) else {
            return Ok(Err(short(p)));
        };
        let idb = id.to_le_bytes();
        let mut r = reply(Port::Param, 3, &[cmd, idb[0], idb[1]]);
        let index = usize::from(id);
        let known = param_entry(index).is_some();
        // Persistent: the flight parameters and `ring.effect` (the TOC's extended flag).
        let persistent = persistent(index);
        match cmd {
            // Extended type: 1, persistent (status 0 first, protocol 11+).
            misc::GET_EXTENDED_TYPE_V2 if known => {
                let _ = r.extend(&[0, u8::from(persistent)]);
            }
            misc::GET_DEFAULT_VALUE_V2 if known => {
                let _ = r.extend(&[0]);
                let v = self.param_default(index).unwrap_or(0.0);
                self.put_value(&mut r, index, v);
            }
            // Store the value in force, get the state, clear: as the
            // Crazyflie's persistent parameters, answered by the link's
            // owner with its storage ([`CrtpShared::take_persist`]). One at
            // a time: another is not answered (cflib asks again).
            misc::PERSISTENT_STORE..=misc::PERSISTENT_CLEAR if persistent => {
                if self.persist.is_some() {
                    return Ok(Err(CrtpError::Refused { port: p.port() }));
                }
                self.persist = Some(PersistRequest {
                    cmd,
                    id,
                    now: self.param_value(index).unwrap_or(0.0),
                    default: self.param_default(index).unwrap_or(0.0),
                    ty: param_entry(index).map_or(param_types::FLOAT, |(_, t, _)| t),
                });
                return Ok(Ok(()));
            }
            // Not persistent, and unknown ids.
            misc::PERSISTENT_STORE..=misc::PERSISTENT_CLEAR
            | misc::GET_EXTENDED_TYPE_V2
            | misc::GET_DEFAULT_VALUE_V2 => {
                let _ = r.extend(&[log::ENOENT]);
            }
            _ => return Ok(Err(unsupported(p))),
        }
        out.send(&r)?;
        Ok(Ok(()))
    }

    /// `MISC_SETBYNAME`: `[0, group\0, name\0, type, value]`, answered
    /// `[0, group\0, name\0, error]`.
    pub(in crate::vehicle) fn on_set_by_name<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        let d = &p.payload()[1..];
        let mut parts = d.splitn(3, |&b| b == 0);
        let (Some(group), Some(name), Some(rest)) = (parts.next(), parts.next(), parts.next()) else {
            return Ok(Err(short(p)));
        };
        let Some((&t, value)) = rest.split_first() else {
            return Ok(Err(short(p)));
        };
        let id = param_named(group, name);
        if id.is_some() && self.busy() {
            // As a write by id: not answered until the design under way is done.
            return Ok(Err(CrtpError::Refused { port: p.port() }));
        }
        let code = match (id, read_value(t, value)) {
            (None, _) => log::ENOENT,
            // The type as the firmware compares it: without its flags.
            (Some(i), Some(v)) if param_entry(i).is_some_and(|(_, pt, _)| same_type(pt, t)) => {
                match self.param_write(i, v, Reply::Crtp(*p)) {
                    Ok(Written::Later) => return Ok(Ok(())),
                    Ok(Written::Now) => 0,
                    Err(_) => log::ENOEXEC,
                }
            }
            _ => log::ENOEXEC,
        };
        out.send(&set_by_name_reply(p, code))?;
        Ok(if code == 0 {
            Ok(())
        } else {
            Err(CrtpError::Refused { port: p.port() })
        })
    }
}
