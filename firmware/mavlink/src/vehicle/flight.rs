//! The modes' flight: mode switches, offboard set-points
//! (`SET_POSITION_TARGET_LOCAL_NED`), manual control, the ground-station
//! loss failsafe, the land detector.

use super::{
    joystick_velocity, FlightMode, Legs, MavFrame, MavLandedState, MavSeverity, MavSink, MavVehicle,
    PositionTargetTypemask, Reference, Setpoint, Vector3, IN_AIR_M, SET_POSITION_TARGET_LOCAL_NED_DATA,
};

/// The longest gap between two streamed accelerations that still gives a
/// jerk, ms (an Offboard stream comes at 10–50 Hz; PX4 leaves Offboard
/// after 1 s without one).
pub const JERK_GAP_MAX_MS: u32 = 100;

/// The largest jerk taken from a stream, m/s³ per axis: a change of
/// acceleration steeper than this is a new set-point, not a trajectory's
/// slope (a 1 m, 6 s figure-8 asks for 4.6).
pub const JERK_MAX_MPS3: f32 = 50.0;

/// The jerk feed-forward of a streamed trajectory, m/s³ NED:
/// `SET_POSITION_TARGET_LOCAL_NED` carries position, velocity and
/// acceleration but no jerk, and without it the controllers fly a moving
/// reference with no attitude-rate feed-forward (a figure-8's error grows
/// tenfold). The slope of the acceleration between the `last` streamed
/// one and `acc`, over the sender's clock (`time_boot_ms`); zero when
/// there is no last one, the gap is not in (0, [`JERK_GAP_MAX_MS`]] ms, or
/// the slope is steeper than [`JERK_MAX_MPS3`] on an axis (a step).
pub fn streamed_jerk(last: Option<(Vector3<f32>, u32)>, acc: Vector3<f32>, t_ms: u32) -> Vector3<f32> {
    let Some((a0, t0)) = last else {
        return Vector3::zeros();
    };
    let gap = t_ms.wrapping_sub(t0);
    if gap == 0 || gap > JERK_GAP_MAX_MS {
        return Vector3::zeros();
    }
    let j = (acc - a0) / (gap as f32 * 1e-3);
    if j.iter().all(|v| v.is_finite() && v.abs() <= JERK_MAX_MPS3) {
        j
    } else {
        Vector3::zeros()
    }
}

/// Whether a `SET_POSITION_TARGET_LOCAL_NED` masks its acceleration (any
/// axis).
fn acc_masked(mask: PositionTargetTypemask) -> bool {
    use PositionTargetTypemask as T;
    mask.intersects(
        T::POSITION_TARGET_TYPEMASK_AX_IGNORE
            | T::POSITION_TARGET_TYPEMASK_AY_IGNORE
            | T::POSITION_TARGET_TYPEMASK_AZ_IGNORE,
    )
}

/// `SET_POSITION_TARGET_LOCAL_NED` as a set-point: `None` unless the frame
/// is `MAV_FRAME_LOCAL_NED` and the position is given. A masked yaw keeps
/// `yaw_rad`. The values are not checked here:
/// [`fc_loop::Loop::set_setpoint`] refuses what is not finite or in range.
pub fn setpoint_from_target(m: &SET_POSITION_TARGET_LOCAL_NED_DATA, yaw_rad: f32) -> Option<Setpoint<f32>> {
    use PositionTargetTypemask as T;
    let mask = m.type_mask;
    let pos_masked = T::POSITION_TARGET_TYPEMASK_X_IGNORE
        | T::POSITION_TARGET_TYPEMASK_Y_IGNORE
        | T::POSITION_TARGET_TYPEMASK_Z_IGNORE;
    if m.coordinate_frame != MavFrame::MAV_FRAME_LOCAL_NED
        || mask.intersects(pos_masked)
        || mask.contains(T::POSITION_TARGET_TYPEMASK_FORCE_SET)
    {
        return None;
    }
    let vel_masked = mask.intersects(
        T::POSITION_TARGET_TYPEMASK_VX_IGNORE
            | T::POSITION_TARGET_TYPEMASK_VY_IGNORE
            | T::POSITION_TARGET_TYPEMASK_VZ_IGNORE,
    );
    let yaw = if mask.contains(T::POSITION_TARGET_TYPEMASK_YAW_IGNORE) {
        yaw_rad
    } else {
        m.yaw
    };
    let mut sp = Setpoint::hold(Vector3::new(m.x, m.y, m.z), yaw);
    if !vel_masked {
        sp.vel_ned_mps = Vector3::new(m.vx, m.vy, m.vz);
    }
    if !acc_masked(mask) {
        sp.acc_ned_mps2 = Vector3::new(m.afx, m.afy, m.afz);
    }
    if !mask.contains(T::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE) {
        sp.yaw_rate_radps = m.yaw_rate;
    }
    Some(sp)
}

impl MavVehicle {
    /// Enters `mode` at `t_us` (see [`crate::modes`]).
    pub(in crate::vehicle) fn set_mode(
        &mut self,
        mode: FlightMode,
        t_us: u64,
        alt_amsl_m: f32,
    ) -> Result<(), &'static str> {
        let est = self.flight.navigator().estimate();
        let here = est.map(|e| e.pos_ned_m);
        let yaw = est.map_or(0.0, |e| fc_core::quat_to_euler(&e.att)[2]);
        match mode {
            FlightMode::Position | FlightMode::Hold => {
                if let (true, Some(p)) = (self.armed, here) {
                    self.flight.set_setpoint(&Setpoint::hold(p, yaw));
                }
            }
            FlightMode::Offboard => {
                let fresh = self
                    .offboard
                    .filter(|&(_, at)| t_us.saturating_sub(at) <= self.offboard_loss_us());
                let Some((sp, _)) = fresh else {
                    return Err("no set-points streaming");
                };
                if self.armed {
                    self.flight.set_setpoint(&sp);
                }
            }
            FlightMode::Mission => {
                if self.mission.items().is_empty() {
                    return Err("no mission");
                }
                if !self.armed {
                    return Err("disarmed");
                }
                if usize::from(self.mission.current()) >= self.mission.items().len() {
                    self.mission.set_current(0);
                }
                self.mission_phase = None;
                self.mission_cruise_mps = None;
            }
            FlightMode::Takeoff | FlightMode::Land | FlightMode::Return => {
                if !self.armed {
                    return Err("disarmed");
                }
                let Some(p) = here else {
                    return Err("no position");
                };
                let ground = self.home_ned_m[2];
                let mut legs = Legs::new();
                let _ = match mode {
                    FlightMode::Takeoff => {
                        let above_origin = self.home.map_or(f32::NAN, |h| alt_amsl_m - h.alt_mm as f32 * 1e-3);
                        let up = if above_origin.is_finite() {
                            above_origin
                        } else {
                            self.nav.takeoff_alt_m - ground
                        };
                        legs.push_back((Vector3::new(p[0], p[1], -up), self.nav.climb_mps))
                    }
                    FlightMode::Land => legs.push_back((Vector3::new(p[0], p[1], ground), self.nav.land_mps)),
                    _ => {
                        // Return: up to RTL_RETURN_ALT (if lower), over home, down.
                        let cruise = p[2].min(ground - self.nav.rtl_alt_m);
                        let h = self.home_ned_m;
                        let _ = legs.push_back((Vector3::new(p[0], p[1], cruise), self.nav.climb_mps));
                        let _ = legs.push_back((Vector3::new(h[0], h[1], cruise), self.nav.cruise_mps));
                        legs.push_back((Vector3::new(h[0], h[1], ground), self.nav.land_mps))
                    }
                };
                let from = Reference::from(self.flight.setpoint());
                if !self.route.start(t_us, &from, legs, self.flight.setpoint().yaw_rad) {
                    return Err("goal out of range");
                }
            }
        }
        if mode != FlightMode::Mission {
            self.mission_phase = None;
        }
        self.mode = mode;
        Ok(())
    }

    pub(in crate::vehicle) fn offboard_loss_us(&self) -> u64 {
        (self.nav.offboard_loss_s * 1e6) as u64
    }

    /// Each step, what the mode flies: the automatic mode's route (a
    /// takeoff then holds; a return or a landing disarms on the ground),
    /// Offboard's loss of set-points (then Hold).
    pub(in crate::vehicle) fn fly_mode<S: MavSink>(
        &mut self,
        t_us: u64,
        dt_s: f32,
        out: &mut S,
    ) -> Result<(), S::Error> {
        if !self.armed {
            return Ok(());
        }
        match self.mode {
            FlightMode::Position => return self.fly_joystick(t_us, dt_s, out),
            FlightMode::Takeoff | FlightMode::Land | FlightMode::Return => {
                let Some((r, done)) = self.route.at(t_us) else {
                    return Ok(());
                };
                self.flight.set_setpoint(&r.setpoint());
                if self.mode == FlightMode::Takeoff && done {
                    self.mode = FlightMode::Hold;
                    return self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("takeoff done: hold"));
                }
                // Landed (fc_loop::land): landing, on the ground it armed on
                // and not moving up or down.
                let landing = self.mode == FlightMode::Land || self.route_descending();
                let on_ground = self
                    .flight
                    .navigator()
                    .estimate()
                    .is_some_and(|e| fc_loop::land::on_ground(&e, self.home_ned_m[2]));
                if landing && on_ground {
                    self.disarm();
                    return self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("landed: disarmed"));
                }
            }
            FlightMode::Mission => return self.fly_mission(t_us, out),
            FlightMode::Offboard => {
                let lost = self
                    .offboard
                    .is_none_or(|(_, at)| t_us.saturating_sub(at) > self.offboard_loss_us());
                if lost {
                    let _ = self.set_mode(FlightMode::Hold, t_us, f32::NAN);
                    return self.say(
                        out,
                        MavSeverity::MAV_SEVERITY_WARNING,
                        format_args!("offboard set-points lost: hold"),
                    );
                }
            }
            _ => {}
        }
        Ok(())
    }

    /// Position mode's step: the joystick moves the set-point
    /// ([`joystick_velocity`]); a joystick heard and then silent for
    /// `COM_RC_LOSS_T` is lost: Land, as for a lost ground station.
    pub(in crate::vehicle) fn fly_joystick<S: MavSink>(
        &mut self,
        t_us: u64,
        dt_s: f32,
        out: &mut S,
    ) -> Result<(), S::Error> {
        let Some(([x, y, z, r], at)) = self.manual else {
            return Ok(());
        };
        if t_us.saturating_sub(at) as f32 * 1e-6 > self.nav.manual_loss_s {
            self.manual = None;
            if self.set_mode(FlightMode::Land, t_us, f32::NAN).is_ok() {
                return self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_CRITICAL,
                    format_args!("joystick lost: landing"),
                );
            }
            return Ok(());
        }
        let mut sp = *self.flight.setpoint();
        let (v, yaw_rate) = joystick_velocity(&self.nav, x, y, z, r, sp.yaw_rad);
        let dt = dt_s.clamp(0.0, 0.1);
        sp.pos_ned_m += v * dt;
        // Not below the ground it armed on (throttle down on the ground).
        sp.pos_ned_m[2] = sp.pos_ned_m[2].min(self.home_ned_m[2]);
        sp.yaw_rad = fc_core::control::wrap_pi(sp.yaw_rad + yaw_rate * dt);
        sp.vel_ned_mps = v;
        sp.acc_ned_mps2 = Vector3::zeros();
        sp.yaw_rate_radps = yaw_rate;
        self.flight.set_setpoint(&sp);
        Ok(())
    }

    /// The ground-station failsafe (`FS_GCS_MS`): armed, a ground station
    /// was heard, and it has been silent that long → Land (where it is,
    /// then disarmed on the ground). Set-points no longer count; a
    /// heartbeat again does not cancel it (as PX4's data-link loss).
    pub(in crate::vehicle) fn watch_ground_station<S: MavSink>(
        &mut self,
        now_us: u64,
        out: &mut S,
    ) -> Result<(), S::Error> {
        let limit_us = u64::from(self.flight.settings().gcs_loss_ms) * 1000;
        let lost = self.gcs_seen_us.is_some_and(|t| now_us.saturating_sub(t) > limit_us);
        if self.armed
            && self.mode != FlightMode::Land
            && limit_us > 0
            && lost
            && self.set_mode(FlightMode::Land, now_us, f32::NAN).is_ok()
        {
            self.gcs_seen_us = None;
            self.say(
                out,
                MavSeverity::MAV_SEVERITY_CRITICAL,
                format_args!("ground station lost: landing"),
            )?;
        }
        Ok(())
    }

    /// Armed and more than [`IN_AIR_M`] above where it armed (estimated):
    /// disarming would drop it.
    pub(in crate::vehicle) fn in_air(&self) -> bool {
        let down = self.flight.navigator().estimate().map(|e| e.pos_ned_m[2]);
        self.armed && down.is_some_and(|d| d < self.home_ned_m[2] - IN_AIR_M)
    }

    /// PX4's landed state: on the ground, taking off, in the air, landing.
    pub fn landed_state(&self) -> MavLandedState {
        let landing = self.mode == FlightMode::Land || self.route_descending();
        match (self.armed, self.in_air()) {
            (false, _) => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
            (true, _) if self.mode == FlightMode::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
            (true, true) if landing => MavLandedState::MAV_LANDED_STATE_LANDING,
            (true, true) => MavLandedState::MAV_LANDED_STATE_IN_AIR,
            (true, false) => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
        }
    }

    /// A return's last leg (straight down over home) is under way.
    pub(in crate::vehicle) fn route_descending(&self) -> bool {
        self.mode == FlightMode::Return && self.route.on_last_leg()
    }

    pub(in crate::vehicle) fn on_setpoint<S: MavSink>(
        &mut self,
        m: &SET_POSITION_TARGET_LOCAL_NED_DATA,
        out: &mut S,
    ) -> Result<(), S::Error> {
        if !self.for_me(m.target_system) {
            self.counters.ignored = self.counters.ignored.wrapping_add(1);
            return Ok(());
        }
        // The frame and mask here; the values (finite, within range) by the
        // flight loop, as for every protocol. Kept for Offboard; flown only
        // in Offboard, as PX4 does. A masked heading keeps the one held:
        // armed, the set-point's; on the ground, the vehicle's own, so a
        // take-off in Offboard keeps the heading it has.
        let held_yaw = match (self.armed, self.flight.navigator().estimate()) {
            (false, Some(e)) => fc_core::quat_to_euler(&e.att)[2],
            _ => self.flight.setpoint().yaw_rad,
        };
        let sp = setpoint_from_target(m, held_yaw).filter(|sp| sp.is_valid());
        match sp {
            Some(mut sp) => {
                let last = self.offboard_acc.take();
                if !acc_masked(m.type_mask) {
                    sp.jerk_ned_mps3 = streamed_jerk(last, sp.acc_ned_mps2, m.time_boot_ms);
                    self.offboard_acc = Some((sp.acc_ned_mps2, m.time_boot_ms));
                }
                self.offboard = Some((sp, self.last_sensor_us.unwrap_or(0)));
                if self.mode == FlightMode::Offboard && self.armed {
                    self.flight.set_setpoint(&sp);
                }
                Ok(())
            }
            None => {
                self.counters.setpoints_refused = self.counters.setpoints_refused.wrapping_add(1);
                self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    format_args!("set-point refused: LOCAL_NED, position, finite"),
                )
            }
        }
    }
}
