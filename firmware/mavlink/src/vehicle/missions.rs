//! The mission flown ([`fc_loop::modes`] flies it) read from the mission
//! micro-service's store ([`crate::mission`]), and what the flight stack's
//! modes say, as the ground station hears it.

use super::{
    say, Home, MavMessage, MavSeverity, MavSink, Mission, Peer, MISSION_CURRENT_DATA, MISSION_ITEM_REACHED_DATA,
};
use crate::mission::MissionAction;
use fc_loop::modes::{MissionItems, ModeEvent};

/// The store's items as the flight stack flies them, about `origin` (the
/// local frame's origin: the simulator's first position).
pub(in crate::vehicle) struct Flown<'a> {
    pub(in crate::vehicle) mission: &'a mut Mission,
    pub(in crate::vehicle) origin: Home,
}

impl MissionItems for Flown<'_> {
    fn len(&self) -> usize {
        self.mission.items().len()
    }

    fn current(&self) -> u16 {
        self.mission.current()
    }

    fn set_current(&mut self, seq: u16) {
        self.mission.set_current(seq);
    }

    fn action(&self, seq: u16, home_down_m: f32) -> Option<Result<MissionAction, ()>> {
        let item = self.mission.items().get(usize::from(seq))?;
        Some(item.action(&self.origin, home_down_m).map_err(|_| ()))
    }
}

/// A mode's event for the ground station: a mission item reached is
/// `MISSION_ITEM_REACHED` and the current item's `MISSION_CURRENT`, the
/// rest a `STATUSTEXT` saying it.
pub(in crate::vehicle) fn tell<S: MavSink>(out: &mut S, event: ModeEvent) -> Result<(), S::Error> {
    let severity = match event {
        ModeEvent::ItemReached { seq, next } => {
            out.send(
                Peer::GroundStation,
                &MavMessage::MISSION_ITEM_REACHED(MISSION_ITEM_REACHED_DATA { seq }),
            )?;
            return out.send(
                Peer::GroundStation,
                &MavMessage::MISSION_CURRENT(MISSION_CURRENT_DATA { seq: next }),
            );
        }
        ModeEvent::Lockdown => MavSeverity::MAV_SEVERITY_EMERGENCY,
        e if e.is_failsafe() => MavSeverity::MAV_SEVERITY_CRITICAL,
        ModeEvent::OffboardLost | ModeEvent::ItemNotFlyable(_) | ModeEvent::ItemOutOfRange(_) => {
            MavSeverity::MAV_SEVERITY_WARNING
        }
        _ => MavSeverity::MAV_SEVERITY_INFO,
    };
    say(out, severity, format_args!("{event}"))
}

/// `mission` as the flight stack flies it, about the simulator's first
/// position `home` (the origin until there is one).
pub(in crate::vehicle) fn flown(mission: &mut Mission, home: Option<Home>) -> Flown<'_> {
    Flown {
        mission,
        origin: home.unwrap_or_default(),
    }
}
