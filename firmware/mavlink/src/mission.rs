//! The mission protocol (upload, download, clear, current) over a
//! fixed-size store, and what each item flies.
//!
//! Upload: `MISSION_COUNT` → `MISSION_REQUEST_INT` for each item in turn →
//! `MISSION_ITEM_INT` … → `MISSION_ACK`. A request not answered within
//! [`REQUEST_RETRY_US`] of simulated time is sent again, [`REQUEST_RETRIES`]
//! times, then the upload is cancelled (`MAV_MISSION_OPERATION_CANCELLED`,
//! the store left empty). More than [`MISSION_CAPACITY`] items are refused
//! at once (`MAV_MISSION_NO_SPACE`); an item this vehicle cannot fly ends
//! the upload with the reason (`MAV_MISSION_UNSUPPORTED`,
//! `MAV_MISSION_UNSUPPORTED_FRAME`, `MAV_MISSION_INVALID_PARAM5_X`, …).
//! Download: `MISSION_REQUEST_LIST` → `MISSION_COUNT`, then
//! `MISSION_REQUEST_INT` (or `MISSION_REQUEST`) → `MISSION_ITEM_INT`.
//! `MISSION_CLEAR_ALL` empties the store; `MISSION_SET_CURRENT` picks the
//! item a mission starts from.
//!
//! The vehicle's messages are addressed to system 0 (broadcast): the reader
//! gives the vehicle the messages, not their senders.

// The `_INT` frames, `MISSION_REQUEST` and `MISSION_SET_CURRENT` are
// deprecated in the dialect and still what MAVSDK and QGroundControl send.
#![allow(deprecated)]

use crate::hil::Home;
use crate::MavMessage;
use crate::{MavSink, Peer};
use mavlink::dialects::common::*;
use nalgebra::Vector3;

/// Items the store holds.
pub const MISSION_CAPACITY: usize = 16;
/// A request unanswered this long (simulated µs) is sent again: PX4's
/// `MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT`.
pub const REQUEST_RETRY_US: u64 = 250_000;
/// Requests sent again before an upload is cancelled: 5 s of silence,
/// PX4's `MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT`. Over a link that
/// loses 30 % each way, a request and its answer pass together about one
/// time in two; a few retries 0.5 s apart lost whole uploads.
pub const REQUEST_RETRIES: u8 = 20;
/// Farthest a mission item may be from the origin, m (the planner's reach).
pub const MAX_DISTANCE_M: f32 = 1000.0;

/// One mission item, as `MISSION_ITEM_INT` carries it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Item {
    /// What to do.
    pub command: MavCmd,
    /// The frame of `x`, `y`, `z`.
    pub frame: MavFrame,
    /// `param1`–`param4`.
    pub params: [f32; 4],
    /// Latitude × 1e7 (global frames) or north × 1e4 m (local).
    pub x: i32,
    /// Longitude × 1e7 or east × 1e4 m.
    pub y: i32,
    /// Altitude, m (relative to home, above sea level, or down: by frame).
    pub z: f32,
}

/// What an item flies, in the local frame: the flight stack's mission step.
pub use fc_loop::modes::MissionAction;

impl Item {
    /// From the message.
    pub fn from_int(m: &MISSION_ITEM_INT_DATA) -> Self {
        Self {
            command: m.command,
            frame: m.frame,
            params: [m.param1, m.param2, m.param3, m.param4],
            x: m.x,
            y: m.y,
            z: m.z,
        }
    }

    /// As the message, sequence `seq`.
    pub fn to_int(&self, seq: u16, current: bool) -> MISSION_ITEM_INT_DATA {
        MISSION_ITEM_INT_DATA {
            param1: self.params[0],
            param2: self.params[1],
            param3: self.params[2],
            param4: self.params[3],
            x: self.x,
            y: self.y,
            z: self.z,
            seq,
            command: self.command,
            target_system: 0,
            target_component: 0,
            frame: self.frame,
            current: u8::from(current),
            autocontinue: 1,
        }
    }

    /// The item's position in the local frame (NED about `origin`, the
    /// local frame's; `home_down_m` is home's height there), if its frame
    /// has one.
    fn ned(&self, origin: &Home, home_down_m: f32) -> Option<Vector3<f32>> {
        use MavFrame as F;
        let p = match self.frame {
            F::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT | F::MAV_FRAME_GLOBAL_RELATIVE_ALT => {
                let ne = origin.ned_m(self.x, self.y, origin.alt_mm);
                Vector3::new(ne[0] as f32, ne[1] as f32, home_down_m - self.z)
            }
            F::MAV_FRAME_GLOBAL_INT | F::MAV_FRAME_GLOBAL => {
                let ne = origin.ned_m(self.x, self.y, origin.alt_mm);
                Vector3::new(ne[0] as f32, ne[1] as f32, -(self.z - origin.alt_mm as f32 * 1e-3))
            }
            F::MAV_FRAME_LOCAL_NED => Vector3::new(self.x as f32 * 1e-4, self.y as f32 * 1e-4, self.z),
            _ => return None,
        };
        p.iter()
            .all(|v| v.is_finite() && v.abs() <= MAX_DISTANCE_M)
            .then_some(p)
    }

    /// What the item flies, or why this vehicle cannot fly it.
    pub fn action(&self, origin: &Home, home_down_m: f32) -> Result<MissionAction, MavMissionResult> {
        use MavCmd as C;
        let finite_or_0 = |v: f32| if v.is_finite() { v.max(0.0) } else { 0.0 };
        Ok(match self.command {
            C::MAV_CMD_NAV_WAYPOINT => MissionAction::Goto {
                ned: self
                    .ned(origin, home_down_m)
                    .ok_or(MavMissionResult::MAV_MISSION_UNSUPPORTED_FRAME)?,
                hold_s: finite_or_0(self.params[0]),
                accept_m: finite_or_0(self.params[1]),
            },
            C::MAV_CMD_NAV_TAKEOFF => {
                let up = match self.frame {
                    MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT | MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT => self.z,
                    MavFrame::MAV_FRAME_GLOBAL_INT | MavFrame::MAV_FRAME_GLOBAL => {
                        self.z - origin.alt_mm as f32 * 1e-3 + home_down_m
                    }
                    MavFrame::MAV_FRAME_LOCAL_NED => home_down_m - self.z,
                    _ => return Err(MavMissionResult::MAV_MISSION_UNSUPPORTED_FRAME),
                };
                if !(up.is_finite() && up > 0.0 && up <= MAX_DISTANCE_M) {
                    return Err(MavMissionResult::MAV_MISSION_INVALID_PARAM7);
                }
                MissionAction::Takeoff { up_m: up }
            }
            C::MAV_CMD_NAV_LAND => MissionAction::Land,
            C::MAV_CMD_NAV_RETURN_TO_LAUNCH => MissionAction::Return,
            C::MAV_CMD_NAV_DELAY | C::MAV_CMD_NAV_LOITER_TIME => {
                let s = self.params[0];
                if !(s.is_finite() && (0.0..=3600.0).contains(&s)) {
                    return Err(MavMissionResult::MAV_MISSION_INVALID_PARAM1);
                }
                MissionAction::Delay { s }
            }
            C::MAV_CMD_DO_CHANGE_SPEED => {
                let v = self.params[1];
                if !(v.is_finite() && v > 0.0 && v <= 20.0) {
                    return Err(MavMissionResult::MAV_MISSION_INVALID_PARAM2);
                }
                MissionAction::Speed { mps: v }
            }
            _ => return Err(MavMissionResult::MAV_MISSION_UNSUPPORTED),
        })
    }
}

/// An upload under way.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Upload {
    count: u16,
    /// When the last request went out (simulated µs), and how often it was repeated.
    asked_us: u64,
    retries: u8,
}

/// The store and its transfers.
#[derive(Debug, Clone, Default)]
pub struct Mission {
    items: heapless::Vec<Item, MISSION_CAPACITY>,
    upload: Option<Upload>,
    current: u16,
}

fn ack(result: MavMissionResult) -> MavMessage {
    MavMessage::MISSION_ACK(MISSION_ACK_DATA {
        target_system: 0,
        target_component: 0,
        mavtype: result,
    })
}

fn request(seq: u16) -> MavMessage {
    MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
        seq,
        target_system: 0,
        target_component: 0,
    })
}

impl Mission {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            items: heapless::Vec::new(),
            upload: None,
            current: 0,
        }
    }

    /// The items stored (none while an upload is under way).
    pub fn items(&self) -> &[Item] {
        if self.upload.is_some() {
            &[]
        } else {
            &self.items
        }
    }

    /// The item a mission starts from (or goes on with).
    pub fn current(&self) -> u16 {
        self.current
    }

    /// Sets the current item (clamped to the store).
    pub fn set_current(&mut self, seq: u16) {
        self.current = seq.min(self.items.len() as u16);
    }

    /// `MISSION_CURRENT`.
    pub fn current_message(&self) -> MavMessage {
        MavMessage::MISSION_CURRENT(MISSION_CURRENT_DATA { seq: self.current })
    }

    /// A mission-protocol message from the ground station (`origin` and
    /// `home_down_m` check the items' positions; `None` before the
    /// simulator gave an origin: global items are then refused). `false` if
    /// `msg` is not one.
    pub fn handle<S: MavSink>(
        &mut self,
        msg: &MavMessage,
        t_us: u64,
        origin: Option<&Home>,
        home_down_m: f32,
        out: &mut S,
    ) -> Result<bool, S::Error> {
        let gcs = Peer::GroundStation;
        match msg {
            MavMessage::MISSION_COUNT(m) => {
                self.items.clear();
                self.current = 0;
                self.upload = None;
                if usize::from(m.count) > MISSION_CAPACITY {
                    out.send(gcs, &ack(MavMissionResult::MAV_MISSION_NO_SPACE))?;
                } else if m.count == 0 {
                    out.send(gcs, &ack(MavMissionResult::MAV_MISSION_ACCEPTED))?;
                } else {
                    self.upload = Some(Upload {
                        count: m.count,
                        asked_us: t_us,
                        retries: 0,
                    });
                    out.send(gcs, &request(0))?;
                }
            }
            MavMessage::MISSION_ITEM_INT(m) => {
                let Some(up) = self.upload else {
                    return Ok(true);
                };
                let next = self.items.len() as u16;
                if m.seq != next {
                    // Out of order (a repeat): ask again for the one expected.
                    out.send(gcs, &request(next))?;
                    return Ok(true);
                }
                let item = Item::from_int(m);
                let checked = match origin {
                    Some(o) => item.action(o, home_down_m).map(|_| ()),
                    None if item.frame == MavFrame::MAV_FRAME_LOCAL_NED
                        || item.frame == MavFrame::MAV_FRAME_MISSION =>
                    {
                        item.action(&Home::default(), home_down_m).map(|_| ())
                    }
                    None => Err(MavMissionResult::MAV_MISSION_DENIED),
                };
                if let Err(why) = checked.and_then(|()| {
                    self.items
                        .push(item)
                        .map_err(|_| MavMissionResult::MAV_MISSION_NO_SPACE)
                }) {
                    self.items.clear();
                    self.upload = None;
                    out.send(gcs, &ack(why))?;
                } else if self.items.len() as u16 == up.count {
                    self.upload = None;
                    out.send(gcs, &ack(MavMissionResult::MAV_MISSION_ACCEPTED))?;
                } else {
                    self.upload = Some(Upload {
                        asked_us: t_us,
                        retries: 0,
                        ..up
                    });
                    out.send(gcs, &request(next + 1))?;
                }
            }
            MavMessage::MISSION_REQUEST_LIST(_) => {
                out.send(
                    gcs,
                    &MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
                        count: self.items().len() as u16,
                        target_system: 0,
                        target_component: 0,
                    }),
                )?;
            }
            MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA { seq, .. })
            | MavMessage::MISSION_REQUEST(MISSION_REQUEST_DATA { seq, .. }) => {
                match self.items().get(usize::from(*seq)) {
                    Some(item) => out.send(
                        gcs,
                        &MavMessage::MISSION_ITEM_INT(item.to_int(*seq, *seq == self.current)),
                    )?,
                    None => out.send(gcs, &ack(MavMissionResult::MAV_MISSION_INVALID_SEQUENCE))?,
                }
            }
            MavMessage::MISSION_CLEAR_ALL(_) => {
                self.items.clear();
                self.upload = None;
                self.current = 0;
                out.send(gcs, &ack(MavMissionResult::MAV_MISSION_ACCEPTED))?;
            }
            MavMessage::MISSION_SET_CURRENT(m) => {
                self.set_current(m.seq);
                out.send(gcs, &self.current_message())?;
            }
            // The ground station's acknowledgement of a download.
            MavMessage::MISSION_ACK(_) => {}
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Each step: an upload's request not answered is sent again, then the
    /// upload cancelled.
    pub fn tick<S: MavSink>(&mut self, t_us: u64, out: &mut S) -> Result<(), S::Error> {
        let Some(up) = self.upload else {
            return Ok(());
        };
        if t_us.saturating_sub(up.asked_us) < REQUEST_RETRY_US {
            return Ok(());
        }
        if up.retries >= REQUEST_RETRIES {
            self.items.clear();
            self.upload = None;
            return out.send(
                Peer::GroundStation,
                &ack(MavMissionResult::MAV_MISSION_OPERATION_CANCELLED),
            );
        }
        self.upload = Some(Upload {
            asked_us: t_us,
            retries: up.retries + 1,
            ..up
        });
        out.send(Peer::GroundStation, &request(self.items.len() as u16))
    }
}
