//! `SYS_STATUS` (1), 2 Hz: the sensors present and healthy, the load, the
//! refusals' counts; no battery is measured.

use super::Stream;
use crate::vehicle::{MavMessage, MavShared, MavSysStatusSensor, NavMode, SYS_STATUS_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 1,
    name: "SYS_STATUS",
    interval_us: 500_000,
    build: MavShared::sys_status,
};

impl MavShared {
    fn sys_status(&self, _t_us: u64) -> Option<MavMessage> {
        Some(MavMessage::SYS_STATUS(self.sys_status_data()))
    }

    /// The message's fields: what is present and healthy, the load and the
    /// refusals' counts.
    fn sys_status_data(&self) -> SYS_STATUS_DATA {
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
