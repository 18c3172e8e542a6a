//! The telemetry streams: which message each stream sends, at what rate
//! (`SET_MESSAGE_INTERVAL` changes it), built from the flight stack's state.

use super::{
    autopilot_version, boot_ms, hil, EstimatorStatusFlags, MavMessage, MavShared, MavSink, MavSysStatusSensor,
    MavVtolState, NavMode, Peer, Px4Mode, ATTITUDE_DATA, ATTITUDE_QUATERNION_DATA, AUTOPILOT_VERSION_ID,
    ESTIMATOR_STATUS_DATA, EXTENDED_SYS_STATE_DATA, GLOBAL_POSITION_INT_DATA, HOME_POSITION_DATA,
    LOCAL_POSITION_NED_DATA, SYS_STATUS_DATA,
};

/// The telemetry streams and their default intervals, µs of simulated
/// time (`MAV_CMD_SET_MESSAGE_INTERVAL` changes them): message id, interval.
pub const STREAMS: [(u32, u64); 10] = [
    (0, 1_000_000),   // HEARTBEAT, 1 Hz (to the simulator too)
    (1, 500_000),     // SYS_STATUS, 2 Hz
    (30, 20_000),     // ATTITUDE, 50 Hz
    (32, 20_000),     // LOCAL_POSITION_NED, 50 Hz
    (33, 100_000),    // GLOBAL_POSITION_INT, 10 Hz
    (31, 100_000),    // ATTITUDE_QUATERNION, 10 Hz
    (245, 200_000),   // EXTENDED_SYS_STATE, 5 Hz
    (242, 2_000_000), // HOME_POSITION, 0.5 Hz
    (42, 1_000_000),  // MISSION_CURRENT, 1 Hz
    (230, 500_000),   // ESTIMATOR_STATUS, 2 Hz
];

/// The shortest interval a stream may be set to, µs (the IMU's step).
pub const MIN_INTERVAL_US: u64 = 1_000;

impl MavShared {
    /// Sends the telemetry due at simulated time `t_us` ([`STREAMS`], at
    /// their intervals).
    pub(in crate::vehicle) fn telemetry<S: MavSink>(&mut self, t_us: u64, out: &mut S) -> Result<(), S::Error> {
        for (k, &(id, _)) in STREAMS.iter().enumerate() {
            let (interval, next) = self.streams[k];
            if interval == 0 || t_us < next {
                continue;
            }
            self.streams[k].1 = t_us.saturating_add(interval);
            if let Some(m) = self.message(id, t_us) {
                if id == 0 {
                    out.send(Peer::Simulator, &m)?;
                }
                out.send(Peer::GroundStation, &m)?;
            }
        }
        Ok(())
    }

    /// Message `id` as of `t_us`, if this vehicle sends it (and has what it
    /// carries: an estimate, a home).
    pub(in crate::vehicle) fn message(&self, id: u32, t_us: u64) -> Option<MavMessage> {
        let est = self.lp.navigator().estimate();
        let time_boot_ms = boot_ms(t_us);
        Some(match id {
            0 => MavMessage::HEARTBEAT(hil::heartbeat(self.modes.armed(), self.modes.mode().custom_mode())),
            1 => MavMessage::SYS_STATUS(self.sys_status()),
            30 => {
                let e = est?;
                let rpy = fc_core::quat_to_euler(&e.att);
                MavMessage::ATTITUDE(ATTITUDE_DATA {
                    time_boot_ms,
                    roll: rpy[0],
                    pitch: rpy[1],
                    yaw: rpy[2],
                    rollspeed: e.rates_frd_radps[0],
                    pitchspeed: e.rates_frd_radps[1],
                    yawspeed: e.rates_frd_radps[2],
                })
            }
            31 => {
                let e = est?;
                MavMessage::ATTITUDE_QUATERNION(ATTITUDE_QUATERNION_DATA {
                    time_boot_ms,
                    q1: e.att[0],
                    q2: e.att[1],
                    q3: e.att[2],
                    q4: e.att[3],
                    rollspeed: e.rates_frd_radps[0],
                    pitchspeed: e.rates_frd_radps[1],
                    yawspeed: e.rates_frd_radps[2],
                })
            }
            32 => {
                let e = est?;
                MavMessage::LOCAL_POSITION_NED(LOCAL_POSITION_NED_DATA {
                    time_boot_ms,
                    x: e.pos_ned_m[0],
                    y: e.pos_ned_m[1],
                    z: e.pos_ned_m[2],
                    vx: e.vel_ned_mps[0],
                    vy: e.vel_ned_mps[1],
                    vz: e.vel_ned_mps[2],
                })
            }
            33 => {
                let (e, h) = (est?, self.home?);
                let (lat, lon, alt) = h.geodetic(&e.pos_ned_m.cast());
                let cm = |v: f32| (v * 100.0).clamp(-32_767.0, 32_767.0) as i16;
                let yaw_deg = fc_core::quat_to_euler(&e.att)[2].to_degrees();
                MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
                    time_boot_ms,
                    lat,
                    lon,
                    alt,
                    relative_alt: ((self.modes.home_ned_m()[2] - e.pos_ned_m[2]) * 1e3) as i32,
                    vx: cm(e.vel_ned_mps[0]),
                    vy: cm(e.vel_ned_mps[1]),
                    vz: cm(e.vel_ned_mps[2]),
                    hdg: (libm::fmodf(yaw_deg + 360.0, 360.0) * 100.0) as u16 % 36_000,
                })
            }
            242 => {
                let h = self.home?;
                let (latitude, longitude, altitude) = h.geodetic(&self.modes.home_ned_m().cast());
                MavMessage::HOME_POSITION(HOME_POSITION_DATA {
                    latitude,
                    longitude,
                    altitude,
                    x: self.modes.home_ned_m()[0],
                    y: self.modes.home_ned_m()[1],
                    z: self.modes.home_ned_m()[2],
                    q: [1.0, 0.0, 0.0, 0.0],
                    approach_x: 0.0,
                    approach_y: 0.0,
                    approach_z: 0.0,
                })
            }
            245 => MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
                vtol_state: MavVtolState::MAV_VTOL_STATE_UNDEFINED,
                landed_state: self.landed_state(),
            }),
            42 => self.mission.current_message(),
            230 => MavMessage::ESTIMATOR_STATUS(self.estimator_status(t_us)),
            AUTOPILOT_VERSION_ID => MavMessage::AUTOPILOT_VERSION(autopilot_version(self.system_id)),
            _ => return None,
        })
    }

    /// `ESTIMATOR_STATUS`: what the estimator gives (attitude, velocity,
    /// position about the origin and, about the simulator's origin, a
    /// global one) while it navigates; its 1σ position accuracy; the latest
    /// fixes' innovation test ratios as PX4 gives them (the vertical one
    /// the larger of the position's and the barometer's, the heading's as
    /// `mag_ratio`; no height-above-ground or airspeed source: 0).
    pub(in crate::vehicle) fn estimator_status(&self, t_us: u64) -> ESTIMATOR_STATUS_DATA {
        use EstimatorStatusFlags as F;
        let nav = self.lp.navigator();
        let sig = nav.estimator().sigmas();
        let navigating = nav.mode() == NavMode::Navigating;
        let mut flags = F::empty();
        if navigating {
            flags = F::ESTIMATOR_ATTITUDE
                | F::ESTIMATOR_VELOCITY_HORIZ
                | F::ESTIMATOR_VELOCITY_VERT
                | F::ESTIMATOR_POS_HORIZ_REL
                | F::ESTIMATOR_POS_VERT_ABS
                | F::ESTIMATOR_PRED_POS_HORIZ_REL;
            if self.home.is_some() {
                flags |= F::ESTIMATOR_POS_HORIZ_ABS | F::ESTIMATOR_PRED_POS_HORIZ_ABS;
            }
        }
        // PX4 sends the square roots of the estimator's ratios.
        let r = nav.estimator().test_ratios();
        ESTIMATOR_STATUS_DATA {
            time_usec: t_us,
            vel_ratio: libm::sqrtf(r.vel),
            pos_horiz_ratio: libm::sqrtf(r.pos_horiz),
            pos_vert_ratio: libm::sqrtf(r.pos_vert.max(r.alt)),
            mag_ratio: libm::sqrtf(r.yaw),
            hagl_ratio: 0.0,
            tas_ratio: 0.0,
            pos_horiz_accuracy: sig[0].max(sig[1]),
            pos_vert_accuracy: sig[2],
            flags,
        }
    }

    pub(in crate::vehicle) fn sys_status(&self) -> SYS_STATUS_DATA {
        use MavSysStatusSensor as S;
        // The position source: the simulator's state as an external
        // (vision-like) position, and a global one about its origin (home).
        let mut present = S::MAV_SYS_STATUS_SENSOR_3D_GYRO
            | S::MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | S::MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
            | S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
            | S::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
            | S::MAV_SYS_STATUS_SENSOR_VISION_POSITION
            | S::MAV_SYS_STATUS_PREARM_CHECK;
        if self.home.is_some() {
            present |= S::MAV_SYS_STATUS_SENSOR_GPS;
        }
        let mut healthy = present;
        let navigating = self.lp.navigator().mode() == NavMode::Navigating && !self.lp.failsafe();
        if !navigating {
            healthy.remove(
                S::MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
                    | S::MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
                    | S::MAV_SYS_STATUS_SENSOR_VISION_POSITION
                    | S::MAV_SYS_STATUS_SENSOR_GPS
                    | S::MAV_SYS_STATUS_PREARM_CHECK,
            );
        }
        if self.lp.mixer().is_none() {
            healthy.remove(S::MAV_SYS_STATUS_PREARM_CHECK);
        }
        // There is no fence, so none is breached: a clear health bit reads
        // as a breach to ground stations that watch it (MAVProxy's fence
        // module prints "fence breach").
        healthy |= S::MAV_SYS_STATUS_GEOFENCE;
        // Load: the last step's time against a 1 kHz step, per mille.
        let per_step = u64::from(self.cycles.1) / 1000;
        let load = (u64::from(self.cycles.0) * 1000).checked_div(per_step).unwrap_or(0);
        SYS_STATUS_DATA {
            onboard_control_sensors_present: present,
            onboard_control_sensors_enabled: present,
            onboard_control_sensors_health: healthy,
            load: load.min(1000) as u16,
            // No battery is measured (no board input, and a simulator over
            // PX4's HIL interface sends none): unknown, as MAVLink spells it,
            // rather than a model passed off as a measurement.
            voltage_battery: u16::MAX,
            current_battery: -1,
            drop_rate_comm: 0,
            errors_comm: self.link_errors.min(u32::from(u16::MAX)) as u16,
            errors_count1: self.counters.sensors_refused.min(u32::from(u16::MAX)) as u16,
            errors_count2: self.counters.params_refused.min(u32::from(u16::MAX)) as u16,
            errors_count3: self.counters.commands_refused.min(u32::from(u16::MAX)) as u16,
            errors_count4: self.lp.counters().invalid_values.min(u32::from(u16::MAX)) as u16,
            battery_remaining: -1,
        }
    }
}
