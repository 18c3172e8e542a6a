//! Mission mode: the items of the protocol's mission store
//! ([`MissionItems`]) flown one by one.

use super::{FlightMode, ModeCommander, ModeEvent};
use crate::commander::Legs;
use crate::Loop;
use nalgebra::Vector3;

/// What a mission item flies, in the local frame (NED about the origin, m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MissionAction {
    /// Fly to `ned`, hold `hold_s`, reached within `accept_m` (0: the
    /// vehicle's `NAV_ACC_RAD`).
    Goto {
        /// Where, NED, m.
        ned: Vector3<f32>,
        /// Hold there, s.
        hold_s: f32,
        /// Acceptance radius, m (0: the default).
        accept_m: f32,
    },
    /// Climb where it is to `up_m` above home.
    Takeoff {
        /// Height above home, m.
        up_m: f32,
    },
    /// Land where it is.
    Land,
    /// Return to launch.
    Return,
    /// Hold where it is, s.
    Delay {
        /// How long, s.
        s: f32,
    },
    /// The automatic modes' horizontal speed from now on, m/s.
    Speed {
        /// m/s.
        mps: f32,
    },
}

/// The mission Mission mode flies, as the protocol's mission store keeps it.
pub trait MissionItems {
    /// How many items there are (none while an upload is under way).
    fn len(&self) -> usize;
    /// No items.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The item flown next (its sequence number).
    fn current(&self) -> u16;
    /// Makes item `seq` the one flown next.
    fn set_current(&mut self, seq: u16);
    /// What item `seq` flies, home being `home_down_m` down the local
    /// frame: `None` past the last item, `Some(Err(()))` if this vehicle
    /// cannot fly it.
    fn action(&self, seq: u16, home_down_m: f32) -> Option<Result<MissionAction, ()>>;
}

/// The mission item flown.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum MissionPhase {
    /// Flying to `goal` (NED, m); reached within `accept_m`, then held `hold_s`.
    Flying {
        seq: u16,
        goal: Vector3<f32>,
        accept_m: f32,
        hold_s: f32,
    },
    /// Holding until `until_us`.
    Holding { seq: u16, until_us: u64 },
}

impl ModeCommander {
    /// Mission mode's step: the item flown (its route, its hold), then the
    /// next; Land and Return items hand over to those modes; after the
    /// last, Hold. At most every item once per step (a speed change takes
    /// none of the vehicle's time).
    pub(super) fn fly_mission<M: MissionItems + ?Sized, E>(
        &mut self,
        t_us: u64,
        lp: &mut Loop,
        mission: &mut M,
        say: &mut impl FnMut(ModeEvent) -> Result<(), E>,
    ) -> Result<(), E> {
        let nav = lp.settings().nav;
        for _ in 0..=mission.len() {
            match self.phase {
                None => {
                    let seq = mission.current();
                    let Some(step) = mission.action(seq, self.home_ned_m[2]) else {
                        let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN, lp, mission);
                        return say(ModeEvent::MissionDone);
                    };
                    let sp = self.setpoint(t_us, lp);
                    let mut legs = Legs::new();
                    let (goal, accept_m, hold_s) = match step {
                        Ok(MissionAction::Goto { ned, hold_s, accept_m }) => {
                            let cruise = self.mission_cruise_mps.unwrap_or(nav.cruise_mps);
                            let _ = legs.push_back((ned, cruise));
                            (ned, accept_m, hold_s)
                        }
                        Ok(MissionAction::Takeoff { up_m }) => {
                            let goal = Vector3::new(sp.pos_ned_m[0], sp.pos_ned_m[1], self.home_ned_m[2] - up_m);
                            let _ = legs.push_back((goal, nav.climb_mps));
                            (goal, 0.0, 0.0)
                        }
                        Ok(MissionAction::Delay { s }) => {
                            self.phase = Some(MissionPhase::Holding {
                                seq,
                                until_us: t_us.saturating_add((s * 1e6) as u64),
                            });
                            return Ok(());
                        }
                        Ok(MissionAction::Speed { mps }) => {
                            self.mission_cruise_mps = Some(mps);
                            self.reached(seq, mission, say)?;
                            continue;
                        }
                        Ok(next @ (MissionAction::Land | MissionAction::Return)) => {
                            self.reached(seq, mission, say)?;
                            let next = if next == MissionAction::Land {
                                FlightMode::Land
                            } else {
                                FlightMode::Return
                            };
                            let _ = self.set_mode(next, t_us, f32::NAN, lp, mission);
                            return Ok(());
                        }
                        Err(()) => {
                            let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN, lp, mission);
                            return say(ModeEvent::ItemNotFlyable(seq));
                        }
                    };
                    if !self.start_route(t_us, &sp, legs, false) {
                        let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN, lp, mission);
                        return say(ModeEvent::ItemOutOfRange(seq));
                    }
                    self.phase = Some(MissionPhase::Flying {
                        seq,
                        goal,
                        accept_m,
                        hold_s,
                    });
                    return Ok(());
                }
                Some(MissionPhase::Flying {
                    seq,
                    goal,
                    accept_m,
                    hold_s,
                }) => {
                    let Some(done) = self.commander.follow(&mut self.route, t_us) else {
                        return Ok(());
                    };
                    let accept = if accept_m > 0.0 { accept_m } else { nav.acc_rad_m };
                    let near = lp
                        .navigator()
                        .estimate()
                        .is_some_and(|e| (e.pos_ned_m - goal).norm() <= accept);
                    if !(done && near) {
                        return Ok(());
                    }
                    if hold_s > 0.0 {
                        self.phase = Some(MissionPhase::Holding {
                            seq,
                            until_us: t_us.saturating_add((hold_s * 1e6) as u64),
                        });
                        return Ok(());
                    }
                    self.reached(seq, mission, say)?;
                }
                Some(MissionPhase::Holding { seq, until_us }) => {
                    if t_us < until_us {
                        return Ok(());
                    }
                    self.reached(seq, mission, say)?;
                }
            }
        }
        Ok(())
    }

    /// Item `seq` done: the next one current, then said.
    fn reached<M: MissionItems + ?Sized, E>(
        &mut self,
        seq: u16,
        mission: &mut M,
        say: &mut impl FnMut(ModeEvent) -> Result<(), E>,
    ) -> Result<(), E> {
        self.phase = None;
        mission.set_current(seq.saturating_add(1));
        say(ModeEvent::ItemReached {
            seq,
            next: mission.current(),
        })
    }
}
