//! Offboard set-points (`SET_POSITION_TARGET_LOCAL_NED`) decoded for the
//! flight stack's modes ([`fc_loop::modes`]), and each step's mode flight,
//! ground-station failsafe and landed state through them.

use super::{
    missions, MavFrame, MavLandedState, MavSeverity, MavShared, MavSink, PositionTargetTypemask, Setpoint, Vector3,
    SET_POSITION_TARGET_LOCAL_NED_DATA,
};
use fc_loop::modes::LandedState;
#[cfg(feature = "sensor-faults")]
use fc_loop::nav::NavMode;

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

impl MavShared {
    /// The commander's part of a sample's step at `t_us`, `dt_s` after the
    /// last, before the estimator's (commander → estimator → controller, as
    /// for every protocol): the ground-station failsafe (`FS_GCS_MS`,
    /// [`fc_loop::modes::ModeCommander::watch_ground_station`]), then what
    /// the mode flies and its tumble lockdown
    /// ([`fc_loop::modes::ModeCommander::fly`]) into the
    /// set-point this step flies. What happens is kept for the step's end
    /// to tell the ground station ([`MavShared::tell_events`]).
    pub(in crate::vehicle) fn command(&mut self, t_us: u64, dt_s: f32) {
        let limit_ms = self.lp.settings().gcs_loss_ms;
        let mut flown = missions::flown(&mut self.mission, self.home);
        let (events, counters) = (&mut self.events, &mut self.counters);
        let mut keep = |e| {
            if events.push(e).is_err() {
                counters.events_dropped = counters.events_dropped.wrapping_add(1);
            }
            Ok::<(), core::convert::Infallible>(())
        };
        if let Some(e) = self
            .modes
            .watch_ground_station(t_us, limit_ms, &mut self.lp, &mut flown)
        {
            let _ = keep(e);
        }
        #[cfg(feature = "sensor-faults")]
        {
            if self.modes.armed() && self.modes.in_air(&self.lp) && self.faults.gyro_dead(t_us) {
                self.modes.disarm();
                let _ = keep(fc_loop::modes::ModeEvent::GyroDead);
            }
            let silent = self.faults.imu_silent(t_us);
            if let Some(e) = self.modes.watch_imu(t_us, silent, &mut self.lp, &mut flown) {
                let _ = keep(e);
            }
            let known = self.faults.position_known() && self.lp.navigator().mode() != NavMode::Failsafe;
            if let Some(e) = self.modes.watch_position(t_us, known, &mut self.lp, &mut flown) {
                let _ = keep(e);
            }
        }
        let _ = self.modes.fly(t_us, dt_s, &mut self.lp, &mut flown, &mut keep);
    }

    /// Tells the ground station what the commander's part of the step did
    /// ([`MavShared::command`]), in order.
    pub(in crate::vehicle) fn tell_events<S: MavSink>(&mut self, out: &mut S) -> Result<(), S::Error> {
        let events = core::mem::take(&mut self.events);
        for e in events {
            missions::tell(out, e)?;
        }
        Ok(())
    }

    /// PX4's landed state: on the ground, taking off, in the air, landing.
    pub fn landed_state(&self) -> MavLandedState {
        match self.modes.landed_state(&self.lp) {
            LandedState::OnGround => MavLandedState::MAV_LANDED_STATE_ON_GROUND,
            LandedState::Takeoff => MavLandedState::MAV_LANDED_STATE_TAKEOFF,
            LandedState::InAir => MavLandedState::MAV_LANDED_STATE_IN_AIR,
            LandedState::Landing => MavLandedState::MAV_LANDED_STATE_LANDING,
        }
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
        let t_us = self.last_sensor_us.unwrap_or(0);
        let held_yaw = match (self.modes.armed(), self.lp.navigator().estimate()) {
            (false, Some(e)) => fc_core::quat_to_euler(&e.att)[2],
            _ => self.modes.setpoint(t_us, &self.lp).yaw_rad,
        };
        let sp = setpoint_from_target(m, held_yaw).filter(|sp| sp.is_valid());
        match sp {
            Some(mut sp) => {
                let last = self.offboard_acc.take();
                if !acc_masked(m.type_mask) {
                    sp.jerk_ned_mps3 = streamed_jerk(last, sp.acc_ned_mps2, m.time_boot_ms);
                    self.offboard_acc = Some((sp.acc_ned_mps2, m.time_boot_ms));
                }
                self.modes.offboard(sp, t_us);
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
