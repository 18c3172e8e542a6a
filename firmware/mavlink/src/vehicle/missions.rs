//! Flying the mission uploaded through the mission micro-service
//! ([`crate::mission`]): each item's goal, acceptance and hold.

use super::{
    FlightMode, Legs, MavCmd, MavMessage, MavSeverity, MavSink, MavVehicle, MissionPhase, Peer, Reference, Step,
    Vector3, MISSION_CAPACITY, MISSION_ITEM_REACHED_DATA,
};

impl MavVehicle {
    /// Mission mode's step: the item flown (its route, its hold), then the
    /// next; Land and Return items hand over to those modes; after the
    /// last, Hold. At most every item once per step (a speed change takes
    /// none of the vehicle's time).
    pub(in crate::vehicle) fn fly_mission<S: MavSink>(&mut self, t_us: u64, out: &mut S) -> Result<(), S::Error> {
        for _ in 0..=MISSION_CAPACITY {
            match self.mission_phase {
                None => {
                    let seq = self.mission.current();
                    let Some(item) = self.mission.items().get(usize::from(seq)).copied() else {
                        let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                        return self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("mission done: hold"));
                    };
                    let origin = self.home.unwrap_or_default();
                    let sp = *self.flight.setpoint();
                    let from = Reference::from(&sp);
                    let mut legs = Legs::new();
                    let (goal, accept_m, hold_s) = match item.step(&origin, self.home_ned_m[2]) {
                        Ok(Step::Goto { ned, hold_s, accept_m }) => {
                            let cruise = self.mission_cruise_mps.unwrap_or(self.nav.cruise_mps);
                            let _ = legs.push_back((ned, cruise));
                            (ned, accept_m, hold_s)
                        }
                        Ok(Step::Takeoff { up_m }) => {
                            let goal = Vector3::new(sp.pos_ned_m[0], sp.pos_ned_m[1], self.home_ned_m[2] - up_m);
                            let _ = legs.push_back((goal, self.nav.climb_mps));
                            (goal, 0.0, 0.0)
                        }
                        Ok(Step::Delay { s }) => {
                            self.mission_phase = Some(MissionPhase::Holding {
                                seq,
                                until_us: t_us.saturating_add((s * 1e6) as u64),
                            });
                            return Ok(());
                        }
                        Ok(Step::Speed { mps }) => {
                            self.mission_cruise_mps = Some(mps);
                            self.mission_reached(seq, out)?;
                            continue;
                        }
                        Ok(Step::Land) | Ok(Step::Return) => {
                            self.mission_reached(seq, out)?;
                            let next = if item.command == MavCmd::MAV_CMD_NAV_LAND {
                                FlightMode::Land
                            } else {
                                FlightMode::Return
                            };
                            let _ = self.set_mode(next, t_us, f32::NAN);
                            return Ok(());
                        }
                        Err(_) => {
                            let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                            return self.say(
                                out,
                                MavSeverity::MAV_SEVERITY_WARNING,
                                format_args!("mission item {seq} cannot be flown: hold"),
                            );
                        }
                    };
                    if !self.route.start(t_us, &from, legs, sp.yaw_rad) {
                        let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                        return self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            format_args!("mission item {seq} out of range: hold"),
                        );
                    }
                    self.mission_phase = Some(MissionPhase::Flying {
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
                    let Some((r, done)) = self.route.at(t_us) else {
                        return Ok(());
                    };
                    self.flight.set_setpoint(&r.setpoint());
                    let accept = if accept_m > 0.0 { accept_m } else { self.nav.acc_rad_m };
                    let near = self
                        .flight
                        .navigator()
                        .estimate()
                        .is_some_and(|e| (e.pos_ned_m - goal).norm() <= accept);
                    if !(done && near) {
                        return Ok(());
                    }
                    if hold_s > 0.0 {
                        self.mission_phase = Some(MissionPhase::Holding {
                            seq,
                            until_us: t_us.saturating_add((hold_s * 1e6) as u64),
                        });
                        return Ok(());
                    }
                    self.mission_reached(seq, out)?;
                }
                Some(MissionPhase::Holding { seq, until_us }) => {
                    if t_us < until_us {
                        return Ok(());
                    }
                    self.mission_reached(seq, out)?;
                }
            }
        }
        Ok(())
    }

    /// Item `seq` done: `MISSION_ITEM_REACHED`, the next one current.
    pub(in crate::vehicle) fn mission_reached<S: MavSink>(&mut self, seq: u16, out: &mut S) -> Result<(), S::Error> {
        self.mission_phase = None;
        out.send(
            Peer::GroundStation,
            &MavMessage::MISSION_ITEM_REACHED(MISSION_ITEM_REACHED_DATA { seq }),
        )?;
        self.mission.set_current(seq.saturating_add(1));
        out.send(Peer::GroundStation, &self.mission.current_message())
    }
}
