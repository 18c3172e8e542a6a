//! PX4's simulator interface in the core's types.
//!
//! A simulator that speaks it (PX4 SITL's, jMAVSim, Gazebo's bridge,
//! rotorpy's `PX4Multirotor`) listens on TCP 4560; the flight controller
//! connects, sends `HEARTBEAT`, and for each `HIL_SENSOR` runs one step
//! and answers one `HIL_ACTUATOR_CONTROLS` (lockstep). This module maps
//! the messages; the flight loop runs the steps.
//!
//! Conventions: `HIL_SENSOR` is body FRD (m/s² specific force, rad/s);
//! `HIL_STATE_QUATERNION`'s position is WGS-84 (1e-7°, mm) and becomes NED
//! metres about a [`Home`] by the equirectangular (small-area) projection,
//! as rotorpy itself makes it; its velocity is NED cm/s and its quaternion
//! body → NED, scalar first. Its position, velocity and heading are used as
//! a mocap-like fix with the σ of [`StateFixSigmas`] (the simulator sends
//! the truth). Motor outputs are in the mixer's unit (rotorpy reads a
//! fraction of its maximum rotor speed).

use crate::common::{
    HilActuatorControlsFlags, HilSensorUpdatedFlags, MavAutopilot, MavModeFlag, MavState, MavType, HEARTBEAT_DATA,
    HIL_ACTUATOR_CONTROLS_DATA, HIL_SENSOR_DATA, HIL_STATE_QUATERNION_DATA,
};
use fc_core::estimate::{Fix, ImuSample};
use nalgebra::{Vector3, Vector4};

/// WGS-84 semi-major axis, m (the projection's sphere).
pub const EARTH_RADIUS_M: f64 = 6_378_137.0;

/// Why a HIL message was not used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HilError {
    /// `HIL_SENSOR` without all of its accelerometer and gyro fields flagged updated.
    NoInertialData,
    /// A field that is not finite or out of its range (named).
    Invalid(&'static str),
}

impl core::fmt::Display for HilError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            HilError::NoInertialData => write!(f, "HIL_SENSOR without updated accelerometer and gyro fields"),
            HilError::Invalid(field) => write!(f, "HIL message field {field} is not finite or out of range"),
        }
    }
}

/// One `HIL_SENSOR`, as the estimator takes it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HilImu {
    /// The simulator's time, µs.
    pub time_us: u64,
    /// Gyro and accelerometer, body FRD.
    pub imu: ImuSample,
    /// Barometric altitude (up), m, when the message flags it updated.
    pub baro_alt_m: Option<f32>,
    /// Magnetic field, body FRD, gauss, when the message flags all three
    /// axes updated (finite, not zero).
    pub mag_frd_gauss: Option<Vector3<f32>>,
}

/// The `HIL_SENSOR` flags of the six inertial fields (accelerometer and
/// gyro, x y z), all of which a sample must have updated.
pub fn inertial_flags() -> HilSensorUpdatedFlags {
    HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XACC
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YACC
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZACC
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XGYRO
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YGYRO
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZGYRO
}

/// `HIL_SENSOR` → IMU sample. Refused unless the six inertial fields are
/// flagged updated and finite.
pub fn imu_from_hil_sensor(m: &HIL_SENSOR_DATA) -> Result<HilImu, HilError> {
    if !m.fields_updated.contains(inertial_flags()) {
        return Err(HilError::NoInertialData);
    }
    let named = [
        ("xacc", m.xacc),
        ("yacc", m.yacc),
        ("zacc", m.zacc),
        ("xgyro", m.xgyro),
        ("ygyro", m.ygyro),
        ("zgyro", m.zgyro),
    ];
    if let Some((name, _)) = named.iter().find(|(_, v)| !v.is_finite()) {
        return Err(HilError::Invalid(name));
    }
    let baro = m
        .fields_updated
        .contains(HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_PRESSURE_ALT)
        .then_some(m.pressure_alt)
        .filter(|a| a.is_finite());
    let mag_flags = HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_XMAG
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_YMAG
        | HilSensorUpdatedFlags::HIL_SENSOR_UPDATED_ZMAG;
    let mag = Vector3::new(m.xmag, m.ymag, m.zmag);
    let mag =
        (m.fields_updated.contains(mag_flags) && mag.iter().all(|v| v.is_finite()) && mag.norm() > 0.0).then_some(mag);
    Ok(HilImu {
        time_us: m.time_usec,
        imu: ImuSample {
            gyro_frd_radps: Vector3::new(m.xgyro, m.ygyro, m.zgyro),
            accel_frd_mps2: Vector3::new(m.xacc, m.yacc, m.zacc),
        },
        baro_alt_m: baro,
        mag_frd_gauss: mag,
    })
}

/// The magnetic heading, rad: the field `mag_frd` (body FRD) levelled with
/// roll `roll_rad` and pitch `pitch_rad` (ZYX Euler), and the angle of its
/// horizontal part from the body's heading, `−atan2(m_y, m_x)`. It is the
/// heading up to the magnetic declination (which the caller references
/// out); `None` when the field is (nearly) vertical.
pub fn mag_heading_rad(mag_frd: &Vector3<f32>, roll_rad: f32, pitch_rad: f32) -> Option<f32> {
    let (sp, cp) = (libm::sinf(roll_rad), libm::cosf(roll_rad));
    let (st, ct) = (libm::sinf(pitch_rad), libm::cosf(pitch_rad));
    let (mx, my, mz) = (mag_frd[0], mag_frd[1], mag_frd[2]);
    let hx = mx * ct + (my * sp + mz * cp) * st;
    let hy = my * cp - mz * sp;
    (libm::hypotf(hx, hy) > 1e-3 * mag_frd.norm()).then(|| -libm::atan2f(hy, hx))
}

/// The origin of the local NED frame, as `HIL_STATE_QUATERNION` spells positions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Home {
    /// Latitude, 1e-7 °.
    pub lat_e7: i32,
    /// Longitude, 1e-7 °.
    pub lon_e7: i32,
    /// Altitude (MSL), mm.
    pub alt_mm: i32,
}

impl Home {
    /// The position of `m` as the home (the first state message, typically).
    pub fn of(m: &HIL_STATE_QUATERNION_DATA) -> Self {
        Self {
            lat_e7: m.lat,
            lon_e7: m.lon,
            alt_mm: m.alt,
        }
    }

    /// A WGS-84 position (1e-7 °, mm) in NED metres about this home.
    pub fn ned_m(&self, lat_e7: i32, lon_e7: i32, alt_mm: i32) -> Vector3<f64> {
        let deg = core::f64::consts::PI / 180.0 * 1e-7;
        let lat0 = f64::from(self.lat_e7) * deg;
        // In f64: the differences of two i32 may not fit an i32.
        let north = (f64::from(lat_e7) - f64::from(self.lat_e7)) * deg * EARTH_RADIUS_M;
        let east = (f64::from(lon_e7) - f64::from(self.lon_e7)) * deg * EARTH_RADIUS_M * libm::cos(lat0);
        let down = -(f64::from(alt_mm) - f64::from(self.alt_mm)) * 1e-3;
        Vector3::new(north, east, down)
    }

    /// The WGS-84 position (latitude and longitude 1e-7 °, altitude MSL mm)
    /// of `ned_m` about this home: the inverse of [`Home::ned_m`] (the same
    /// flat-earth approximation, within 1 cm over a few km). Saturates at
    /// the integers' range.
    pub fn geodetic(&self, ned_m: &Vector3<f64>) -> (i32, i32, i32) {
        let deg = core::f64::consts::PI / 180.0 * 1e-7;
        let lat0 = f64::from(self.lat_e7) * deg;
        let lat = f64::from(self.lat_e7) + ned_m[0] / (deg * EARTH_RADIUS_M);
        let lon = f64::from(self.lon_e7) + ned_m[1] / (deg * EARTH_RADIUS_M * libm::cos(lat0));
        let alt = f64::from(self.alt_mm) - ned_m[2] * 1e3;
        // `as` saturates (and maps NaN to 0).
        (
            libm::round(lat) as i32,
            libm::round(lon) as i32,
            libm::round(alt) as i32,
        )
    }
}

/// The 1σ given to a fix made from `HIL_STATE_QUATERNION`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StateFixSigmas {
    /// Position, each axis, m.
    pub pos_m: f32,
    /// Velocity, each axis, m/s.
    pub vel_mps: f32,
    /// Heading, rad.
    pub yaw_rad: f32,
}

impl StateFixSigmas {
    /// Like the SIL's mocap: 2 mm (the message's resolution is 1 mm and
    /// 1e-7° ≈ 1.1 cm of latitude: 1 cm is used), 5 cm/s (1 cm/s steps),
    /// 0.5°.
    pub const MOCAP_LIKE: Self = Self {
        pos_m: 0.01,
        vel_mps: 0.05,
        yaw_rad: 0.0087,
    };
}

/// The message's latitude is within ±90° and its longitude within ±180°.
pub fn on_earth(m: &HIL_STATE_QUATERNION_DATA) -> bool {
    m.lat.unsigned_abs() <= 900_000_000 && m.lon.unsigned_abs() <= 1_800_000_000
}

/// `HIL_STATE_QUATERNION` → a position, velocity and heading fix about
/// `home`, taken now (age 0). `Err` for a non-unit quaternion or a
/// position off the globe.
pub fn fix_from_hil_state(m: &HIL_STATE_QUATERNION_DATA, home: &Home, s: &StateFixSigmas) -> Result<Fix, HilError> {
    if !on_earth(m) {
        return Err(HilError::Invalid("lat/lon"));
    }
    let q = Vector4::from(m.attitude_quaternion);
    if !q.iter().all(|v| v.is_finite()) || (q.norm() - 1.0).abs() > 1e-3 {
        return Err(HilError::Invalid("attitude_quaternion"));
    }
    let pos = home.ned_m(m.lat, m.lon, m.alt);
    let vel = Vector3::new(f32::from(m.vx), f32::from(m.vy), f32::from(m.vz)) / 100.0;
    let yaw = fc_core::quat_to_euler(&q)[2];
    Ok(Fix {
        age_s: 0.0,
        pos_ned_m: Some(pos.cast()),
        pos_sigma_m: Vector3::repeat(s.pos_m),
        vel_ned_mps: Some(vel),
        vel_sigma_mps: s.vel_mps,
        yaw_rad: Some(yaw),
        yaw_sigma_rad: s.yaw_rad,
        ..Fix::EMPTY
    })
}

/// The answer to a `HIL_SENSOR`: the four motor commands (in the mixer's
/// unit) in `controls[0..4]`, the lockstep flag, and the armed mode when
/// `armed` (disarmed: all commands zero).
pub fn actuator_controls(time_us: u64, motors: &[f32; 4], armed: bool) -> HIL_ACTUATOR_CONTROLS_DATA {
    let mut controls = [0.0f32; 16];
    if armed {
        controls[..4].copy_from_slice(motors);
    }
    HIL_ACTUATOR_CONTROLS_DATA {
        time_usec: time_us,
        flags: HilActuatorControlsFlags::HIL_ACTUATOR_CONTROLS_FLAGS_LOCKSTEP,
        controls,
        mode: mode_flags(armed),
    }
}

/// This flight controller's `HEARTBEAT`: a quadrotor with PX4's autopilot id and
/// mode encoding (`custom_mode`, [`crate::modes::Px4Mode::custom_mode`]),
/// HIL enabled, armed or not.
pub fn heartbeat(armed: bool, custom_mode: u32) -> HEARTBEAT_DATA {
    HEARTBEAT_DATA {
        custom_mode,
        mavtype: MavType::MAV_TYPE_QUADROTOR,
        autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
        base_mode: mode_flags(armed) | MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
        system_status: if armed {
            MavState::MAV_STATE_ACTIVE
        } else {
            MavState::MAV_STATE_STANDBY
        },
        mavlink_version: 3,
    }
}

fn mode_flags(armed: bool) -> MavModeFlag {
    let mut m = MavModeFlag::MAV_MODE_FLAG_HIL_ENABLED
        | MavModeFlag::MAV_MODE_FLAG_STABILIZE_ENABLED
        | MavModeFlag::MAV_MODE_FLAG_GUIDED_ENABLED;
    if armed {
        m |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
    }
    m
}
