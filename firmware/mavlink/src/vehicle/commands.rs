//! The command micro-service (`COMMAND_LONG`, `COMMAND_INT`): arming,
//! modes, take-off, land, return, mission start, message intervals;
//! `AUTOPILOT_VERSION`.

use super::{
    missions, AnyController, Command, FlightMode, MavCmd, MavMessage, MavModeFlag, MavProtocolCapability, MavResult,
    MavSeverity, MavShared, MavSink, Peer, Px4Mode, AUTOPILOT_VERSION_DATA, AUTOPILOT_VERSION_ID, COMMAND_ACK_DATA,
    FLIGHT_SW_VERSION, MIN_INTERVAL_US, STREAMS,
};

/// `param2` of a disarm that is obeyed in the air too (MAVLink's magic number).
pub(super) const FORCE: f32 = 21196.0;

/// `AUTOPILOT_VERSION`: the capabilities that are true of this vehicle.
// PARAM_FLOAT is deprecated for PARAM_ENCODE_C_CAST; every parameter here
// is a REAL32, so both are true, and older clients read PARAM_FLOAT.
#[allow(deprecated)]
pub fn autopilot_version(system_id: u8) -> AUTOPILOT_VERSION_DATA {
    use MavProtocolCapability as C;
    AUTOPILOT_VERSION_DATA {
        capabilities: C::MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | C::MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | C::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
            | C::MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | C::MAV_PROTOCOL_CAPABILITY_MISSION_INT
            | C::MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED,
        uid: u64::from(system_id),
        flight_sw_version: FLIGHT_SW_VERSION,
        middleware_sw_version: 0,
        os_sw_version: 0,
        board_version: 0,
        vendor_id: 0,
        product_id: 0,
        flight_custom_version: [0; 8],
        middleware_custom_version: [0; 8],
        os_custom_version: [0; 8],
    }
}

impl MavShared {
    pub(in crate::vehicle) fn on_command<S: MavSink>(
        &mut self,
        ctrl: &mut AnyController<f32>,
        c: &Command,
        out: &mut S,
    ) -> Result<(), S::Error> {
        let p = &c.params;
        // The message a request asks for, sent after its acknowledgement.
        let mut then_send = None;
        let result = match c.command {
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if p[0] == 1.0 => {
                let started = self.lp.mixer().is_some();
                let sensors = match self.faults.arming_refusal() {
                    Some((s, f)) if !self.modes.armed() => {
                        self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            format_args!("arming refused: {s} {f}"),
                        )?;
                        Err(())
                    }
                    _ => Ok(()),
                };
                match sensors.map(|()| self.modes.arm(&mut self.lp, ctrl, started)) {
                    Err(()) => MavResult::MAV_RESULT_TEMPORARILY_REJECTED,
                    Ok(r) => match r {
                        Ok(()) => {
                            self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("armed"))?;
                            MavResult::MAV_RESULT_ACCEPTED
                        }
                        Err(why) => {
                            self.say(
                                out,
                                MavSeverity::MAV_SEVERITY_WARNING,
                                format_args!("arming refused: {why}"),
                            )?;
                            MavResult::MAV_RESULT_TEMPORARILY_REJECTED
                        }
                    },
                }
            }
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM if p[0] == 0.0 => {
                match self.modes.request_disarm(&self.lp, p[1] == FORCE) {
                    Ok(was_armed) => {
                        if was_armed {
                            self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("disarmed"))?;
                        }
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    Err(why) => {
                        self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            format_args!("disarm refused: {why} (force: 21196)"),
                        )?;
                        MavResult::MAV_RESULT_DENIED
                    }
                }
            }
            MavCmd::MAV_CMD_COMPONENT_ARM_DISARM => MavResult::MAV_RESULT_DENIED,
            MavCmd::MAV_CMD_NAV_TAKEOFF => self.mode_command(FlightMode::Takeoff, p[6], out)?,
            MavCmd::MAV_CMD_NAV_LAND => self.mode_command(FlightMode::Land, f32::NAN, out)?,
            MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH => self.mode_command(FlightMode::Return, f32::NAN, out)?,
            MavCmd::MAV_CMD_DO_SET_MODE => {
                // `as` saturates (NaN to 0): an absurd parameter names no mode.
                let base = p[0] as u8;
                let flags = MavModeFlag::from_bits_truncate(base);
                let custom = flags.contains(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED);
                let mode = if custom {
                    FlightMode::from_px4(p[1] as u8, p[2] as u8)
                } else {
                    FlightMode::from_base_mode(flags)
                };
                match mode {
                    Some(m) => self.mode_command(m, f32::NAN, out)?,
                    None if custom => {
                        self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            // As integers: f32's Display would link core's float formatting.
                            format_args!("mode {}/{} not flown here", p[1] as i32, p[2] as i32),
                        )?;
                        MavResult::MAV_RESULT_DENIED
                    }
                    None => {
                        self.say(
                            out,
                            MavSeverity::MAV_SEVERITY_WARNING,
                            format_args!("base mode {base} not flown here"),
                        )?;
                        MavResult::MAV_RESULT_DENIED
                    }
                }
            }
            // The older requests, superseded by REQUEST_MESSAGE, are still
            // what some ground stations send.
            #[allow(deprecated)]
            MavCmd::MAV_CMD_REQUEST_MESSAGE
            | MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
            | MavCmd::MAV_CMD_GET_HOME_POSITION => {
                #[allow(deprecated)]
                let id = match c.command {
                    MavCmd::MAV_CMD_REQUEST_MESSAGE => p[0] as u32,
                    MavCmd::MAV_CMD_GET_HOME_POSITION => 242,
                    _ => AUTOPILOT_VERSION_ID,
                };
                match self.message(id, self.last_sensor_us.unwrap_or(0)) {
                    Some(m) => {
                        then_send = Some(m);
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    None => MavResult::MAV_RESULT_UNSUPPORTED,
                }
            }
            MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL => {
                let (id, us) = (p[0] as u32, p[1]);
                match STREAMS.iter().position(|s| s.id == id) {
                    Some(k) if us.is_finite() && us >= -1.0 => {
                        self.streams[k].0 = if us == -1.0 {
                            0
                        } else if us == 0.0 {
                            STREAMS[k].interval_us
                        } else {
                            (us as u64).max(MIN_INTERVAL_US)
                        };
                        self.streams[k].1 = 0;
                        MavResult::MAV_RESULT_ACCEPTED
                    }
                    Some(_) => MavResult::MAV_RESULT_DENIED,
                    None => MavResult::MAV_RESULT_UNSUPPORTED,
                }
            }
            MavCmd::MAV_CMD_INJECT_FAILURE => self.inject(p, out)?,
            MavCmd::MAV_CMD_MISSION_START => self.mode_command(FlightMode::Mission, f32::NAN, out)?,
            _ => MavResult::MAV_RESULT_UNSUPPORTED,
        };
        if result != MavResult::MAV_RESULT_ACCEPTED {
            self.counters.commands_refused = self.counters.commands_refused.wrapping_add(1);
        }
        out.send(
            Peer::GroundStation,
            &MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                command: c.command,
                result,
            }),
        )?;
        match then_send {
            Some(m) => out.send(Peer::GroundStation, &m),
            None => Ok(()),
        }
    }

    /// A mode asked for (by `DO_SET_MODE` or its own command): entered, or
    /// refused with a `STATUSTEXT` saying why. `alt_amsl_m` is a takeoff's
    /// height above sea level (NaN: `MIS_TAKEOFF_ALT` above home).
    pub(in crate::vehicle) fn mode_command<S: MavSink>(
        &mut self,
        mode: FlightMode,
        alt_amsl_m: f32,
        out: &mut S,
    ) -> Result<MavResult, S::Error> {
        let t_us = self.last_sensor_us.unwrap_or(0);
        // Above sea level to above the local frame's origin (the
        // simulator's first position); NaN without one.
        let up_m = self.home.map_or(f32::NAN, |h| alt_amsl_m - h.alt_mm as f32 * 1e-3);
        let mut flown = missions::flown(&mut self.mission, self.home);
        match self.modes.set_mode(mode, t_us, up_m, &mut self.lp, &mut flown) {
            Ok(()) => Ok(MavResult::MAV_RESULT_ACCEPTED),
            Err(why) => {
                self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    format_args!("{mode} refused: {why}"),
                )?;
                Ok(MavResult::MAV_RESULT_DENIED)
            }
        }
    }
}
