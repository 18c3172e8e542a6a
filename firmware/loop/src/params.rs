//! The flight controller's parameters, as MAVLink's parameter protocol
//! (PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET / PARAM_VALUE), a
//! ground station and our own protocol (`ParamSet`/`ParamRead` → `Param`) see them: one table, [`PARAMS`], of named values, each
//! with its unit, how to read and write it in [`Settings`], and whether a
//! change re-designs the controller (allowed only while disarmed).
//!
//! Each entry carries its names for every protocol: the MAVLink name
//! ([`Param::mavlink_name`]), the CRTP group and name cflib shows
//! ([`Param::crtp_name`], for the first [`CRTP_PARAMS`]) and, for a few, the
//! Crazyflie firmware's own name, which CRTP serves too
//! ([`Param::crtp_alias`]: `pid_attitude.roll_kp` is `PD_ROLL_P`).
//!
//! Each parameter has a true type ([`ParamType`]): a real, or a whole
//! number (choices, bit masks, milliseconds) that CRTP's param TOC declares
//! as `uint8_t` or `uint16_t`. MAVLink carries every value as a
//! `MAV_PARAM_TYPE_REAL32`; there an integer's setter refuses a fraction. A write is
//! applied to a copy of the settings and the copy is checked as a whole
//! ([`Settings::check`]): the vehicle against its plausible ranges, the
//! rotor layout for a mixer that can produce every wrench, the controller
//! id against the controllers this firmware has. A refused write leaves
//! the settings as they were and says why ([`Refusal`], short enough for a
//! `STATUSTEXT`).

use fc_core::control::ControllerSpec;
use fc_core::model::airframe::{Mixer, MotorUnit};

mod refusal;
mod settings;
mod stored;

pub use crate::modes::NavSettings;
pub use refusal::{Num, Refusal};
use settings::within;
pub use settings::{Airframe, Settings};
pub use stored::{load, Loaded};

/// One parameter: its MAVLink name, what it is, and where it lives.
#[derive(Clone, Copy)]
pub struct Param {
    /// The name a ground station shows (at most 16 characters).
    pub id: &'static str,
    /// What it is, with its unit.
    pub doc: &'static str,
    /// Its value in `Settings`.
    pub get: fn(&Settings) -> f32,
    /// Writes `value` into `Settings` (the whole is checked afterwards).
    pub set: fn(&mut Settings, f32) -> Result<(), Refusal>,
    /// A change re-designs the controller (refused while armed).
    pub redesign: bool,
    /// Its true type: what CRTP's param TOC declares, and what a write
    /// must be (an integer's setter refuses a fraction).
    pub ty: ParamType,
    /// Served in CRTP's param TOC too ([`Param::crtp_name`]); every
    /// parameter is served by MAVLink and our own protocol. The ones CRTP
    /// serves come first ([`CRTP_PARAMS`]).
    pub crtp: bool,
    /// The Crazyflie firmware's own name for it, `group.name`
    /// (`pid_attitude.roll_kp`), which CRTP serves as a second entry so
    /// that cfclient's tabs and scripts written for a Crazyflie find it
    /// ([`Param::crtp_alias`]); empty: none.
    pub crazyflie_alias: &'static str,
}

impl Param {
    /// Its MAVLink (and our protocol's) name: [`Param::id`].
    pub const fn mavlink_name(&self) -> &'static str {
        self.id
    }

    /// Its CRTP group and name, if CRTP serves it: the MAVLink name split
    /// at its first `_` (`VEH_MASS` → `veh.MASS`; cflib shows the group in
    /// lower case), or group `fc` for a name without one.
    pub fn crtp_name(&self) -> Option<(&'static str, &'static str)> {
        // By byte, not `split_once`'s pattern search (a lookup by name
        // tries every entry under the link's lock), and with `get`, which
        // cannot panic, where slicing would bring in the formatting of its
        // panic message (kilobytes of flash).
        self.crtp.then(|| {
            let at = self.id.bytes().position(|b| b == b'_');
            at.and_then(|i| Some((self.id.get(..i)?, self.id.get(i + 1..)?)))
                .unwrap_or(("fc", self.id))
        })
    }

    /// Its Crazyflie group and name, if it has one and CRTP serves it
    /// ([`Param::crazyflie_alias`]; [`CRTP_ALIASED`]).
    pub fn crtp_alias(&self) -> Option<(&'static str, &'static str)> {
        if self.crtp {
            self.crazyflie_alias.split_once('.')
        } else {
            None
        }
    }

    /// The same parameter, also served under the Crazyflie's name `alias`
    /// (`group.name`).
    const fn aliased(self, alias: &'static str) -> Self {
        Self {
            crazyflie_alias: alias,
            ..self
        }
    }
}

/// A parameter's true type.
///
/// CRTP's param TOC declares it, so cflib and cfclient write an integer
/// parameter as one (cflib refuses "5.05" for a `uint8_t` before sending
/// it). MAVLink carries every value as a `REAL32` (`AUTOPILOT_VERSION`
/// says `PARAM_ENCODE_C_CAST`); an integer's setter refuses a fraction
/// there ([`Refusal::NotInteger`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamType {
    /// A real number (`float`).
    F32,
    /// A whole number from 0 to 255 (`uint8_t`).
    U8,
    /// A whole number from 0 to 65 535 (`uint16_t`).
    U16,
}

impl ParamType {
    /// The largest value the type holds (`f32::MAX` for a real).
    pub const fn max(self) -> f32 {
        match self {
            ParamType::F32 => f32::MAX,
            ParamType::U8 => 255.0,
            ParamType::U16 => 65_535.0,
        }
    }
}

impl core::fmt::Debug for Param {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.id)
    }
}

/// `value` as a whole number in `[lo, hi]`. (Not inlined: it is called by
/// a dozen setters, and the image's flash is counted.)
#[inline(never)]
fn whole(value: f32, lo: u32, hi: u32) -> Result<u32, Refusal> {
    if !(value >= lo as f32 && value <= hi as f32) {
        return Err(Refusal::Range {
            lo: lo as f32,
            hi: hi as f32,
        });
    }
    if libm::truncf(value) != value {
        return Err(Refusal::NotInteger);
    }
    Ok(value as u32)
}

/// `value` unless it is not finite (the whole is range-checked later).
#[inline(never)]
fn finite(value: f32) -> Result<f32, Refusal> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(Refusal::Range {
            lo: f32::MIN,
            hi: f32::MAX,
        })
    }
}

macro_rules! real {
    ($id:literal, $doc:literal, $redesign:literal, $($field:tt)+) => {
        Param {
            id: $id,
            doc: $doc,
            get: |s| s.$($field)+,
            set: |s, v| {
                s.$($field)+ = finite(v)?;
                Ok(())
            },
            redesign: $redesign,
            ty: ParamType::F32,
            crtp: true,
            crazyflie_alias: "",
        }
    };
}

/// `value` within `[lo, hi]` (NaN is not), else refused with the range.
#[inline(never)]
fn ranged(value: f32, lo: f32, hi: f32) -> Result<f32, Refusal> {
    within(value, lo, hi).map(|()| value)
}

/// An automatic mode's setting ([`NavSettings`], PX4's name): a real
/// checked against its range when written; MAVLink's only (CRTP flies no
/// modes).
macro_rules! nav {
    ($id:literal, $doc:literal, $lo:expr, $hi:expr, $f:ident) => {
        Param {
            id: $id,
            doc: $doc,
            get: |s| s.nav.$f,
            set: |s, v| {
                s.nav.$f = ranged(v, $lo, $hi)?;
                Ok(())
            },
            redesign: false,
            ty: ParamType::F32,
            crtp: false,
            crazyflie_alias: "",
        }
    };
}

/// The PWM range of `s` (the default 1000–2000 µs if its unit is not PWM).
fn pwm(s: &Settings) -> (u16, u16) {
    match s.unit {
        MotorUnit::PwmUs { min_us, max_us } => (min_us, max_us),
        _ => (1000, 2000),
    }
}

/// Every parameter, in `param_index` order.
pub const PARAMS: [Param; 64] = [
    real!("VEH_MASS", "mass, kg", true, vehicle.mass_kg),
    real!(
        "VEH_IXX",
        "inertia about body x (FRD), kg m^2",
        true,
        vehicle.inertia_kgm2[0]
    ),
    real!(
        "VEH_IYY",
        "inertia about body y (FRD), kg m^2",
        true,
        vehicle.inertia_kgm2[1]
    ),
    real!(
        "VEH_IZZ",
        "inertia about body z (FRD), kg m^2",
        true,
        vehicle.inertia_kgm2[2]
    ),
    real!(
        "VEH_ARM",
        "arm of the roll and pitch inputs U2, U3, m",
        true,
        vehicle.arm_m
    ),
    real!("VEH_JR", "rotor inertia, kg m^2", true, vehicle.rotor_inertia_kgm2),
    real!("VEH_KF", "rotor thrust coefficient, N s^2", true, vehicle.kf_ns2),
    real!(
        "VEH_KM",
        "rotor drag-moment coefficient, N m s^2",
        true,
        vehicle.km_nms2
    ),
    real!(
        "VEH_KT_X",
        "translational drag along x, N s/m",
        true,
        vehicle.kt_nspm[0]
    ),
    real!(
        "VEH_KT_Y",
        "translational drag along y, N s/m",
        true,
        vehicle.kt_nspm[1]
    ),
    real!(
        "VEH_KT_Z",
        "translational drag along z, N s/m",
        true,
        vehicle.kt_nspm[2]
    ),
    real!("VEH_KR_X", "rotational drag about x, N m s", true, vehicle.kr_nms[0]),
    real!("VEH_KR_Y", "rotational drag about y, N m s", true, vehicle.kr_nms[1]),
    real!("VEH_KR_Z", "rotational drag about z, N m s", true, vehicle.kr_nms[2]),
    real!("VEH_WMAX", "largest rotor speed, rad/s", true, vehicle.omega_max_radps),
    real!("VEH_TAU_M", "rotor time constant, s", true, vehicle.rotor_tau_s),
    Param {
        id: "MOT_FRAME",
        doc: "rotor layout and motor order: 0 plus (OS4), 1 X rotorpy, 2 X PX4, 3 X Betaflight, 4 X Crazyflie",
        get: |s| Airframe::ALL.iter().position(|a| *a == s.airframe).unwrap_or(0) as f32,
        set: |s, v| {
            s.airframe = Airframe::ALL[whole(v, 0, Airframe::ALL.len() as u32 - 1)? as usize];
            Ok(())
        },
        redesign: false,
        ty: ParamType::U8,
        crtp: true,
        crazyflie_alias: "",
    },
    real!("MOT_HUB_M", "distance of each hub from the centre, m", false, hub_m),
    Param {
        id: "MOT_REV",
        doc: "motors spinning against the frame's default (bit i: motor i+1)",
        get: |s| f32::from(s.reversed),
        set: |s, v| {
            s.reversed = whole(v, 0, 15)? as u8;
            Ok(())
        },
        redesign: false,
        ty: ParamType::U8,
        crtp: true,
        crazyflie_alias: "",
    },
    Param {
        id: "MOT_UNIT",
        doc: "motor command: 0 speed fraction, 1 thrust fraction, 2 PWM us",
        get: |s| match s.unit {
            MotorUnit::SpeedFraction => 0.0,
            MotorUnit::ThrustFraction => 1.0,
            MotorUnit::PwmUs { .. } => 2.0,
        },
        set: |s, v| {
            let (min_us, max_us) = pwm(s);
            s.unit = match whole(v, 0, 2)? {
                0 => MotorUnit::SpeedFraction,
                1 => MotorUnit::ThrustFraction,
                _ => MotorUnit::PwmUs { min_us, max_us },
            };
            Ok(())
        },
        redesign: false,
        ty: ParamType::U8,
        crtp: true,
        crazyflie_alias: "",
    },
    Param {
        id: "MOT_PWM_MIN",
        doc: "PWM at zero rotor speed, us (MOT_UNIT 2)",
        get: |s| f32::from(pwm(s).0),
        set: |s, v| {
            let min_us = whole(v, 500, 2500)? as u16;
            if let MotorUnit::PwmUs { max_us, .. } = s.unit {
                s.unit = MotorUnit::PwmUs { min_us, max_us };
            }
            Ok(())
        },
        redesign: false,
        ty: ParamType::U16,
        crtp: true,
        crazyflie_alias: "",
    },
    Param {
        id: "MOT_PWM_MAX",
        doc: "PWM at the largest rotor speed, us (MOT_UNIT 2)",
        get: |s| f32::from(pwm(s).1),
        set: |s, v| {
            let max_us = whole(v, 500, 2500)? as u16;
            if let MotorUnit::PwmUs { min_us, .. } = s.unit {
                s.unit = MotorUnit::PwmUs { min_us, max_us };
            }
            Ok(())
        },
        redesign: false,
        ty: ParamType::U16,
        crtp: true,
        crazyflie_alias: "",
    },
    Param {
        id: "CTL_ID",
        doc: "controller (the wire ids of the book's controller table)",
        get: |s| s.controller.to_wire().map_or(-1.0, |(id, _)| f32::from(id)),
        set: |s, v| {
            let ff = s.controller.reference == fc_core::control::ReferenceMode::Feedforward;
            s.controller = ControllerSpec::from_wire(whole(v, 0, 255)? as u8, ff).map_err(Refusal::Controller)?;
            Ok(())
        },
        redesign: true,
        ty: ParamType::U8,
        crtp: true,
        crazyflie_alias: "stabilizer.controller",
    },
    Param {
        id: "CTL_FF",
        doc: "feed the reference's derivatives forward: 1 yes, 0 no",
        get: |s| {
            f32::from(u8::from(
                s.controller.reference == fc_core::control::ReferenceMode::Feedforward,
            ))
        },
        set: |s, v| {
            s.controller.reference = if whole(v, 0, 1)? == 1 {
                fc_core::control::ReferenceMode::Feedforward
            } else {
                fc_core::control::ReferenceMode::Thesis
            };
            Ok(())
        },
        redesign: true,
        ty: ParamType::U8,
        crtp: true,
        crazyflie_alias: "",
    },
    Param {
        id: "FS_TIMEOUT_MS",
        doc: "no sensor data for this long: failsafe, ms",
        get: |s| s.failsafe_timeout_ms as f32,
        set: |s, v| {
            s.failsafe_timeout_ms = whole(v, 10, 5_000)?;
            Ok(())
        },
        redesign: false,
        ty: ParamType::U16,
        crtp: true,
        crazyflie_alias: "",
    },
    real!(
        "FS_DESCENT",
        "failsafe thrust, fraction of hover",
        false,
        failsafe_descent
    ),
    Param {
        id: "FS_GCS_MS",
        doc: "no ground-station heartbeat for this long while armed: land, ms (0 off)",
        get: |s| s.gcs_loss_ms as f32,
        set: |s, v| {
            s.gcs_loss_ms = whole(v, 0, 60_000)?;
            Ok(())
        },
        redesign: false,
        ty: ParamType::U16,
        crtp: true,
        crazyflie_alias: "",
    },
    Param {
        id: "HIL_FIX_MS",
        doc: "period of the fixes taken from HIL_STATE_QUATERNION, ms",
        get: |s| s.fix_period_ms as f32,
        set: |s, v| {
            s.fix_period_ms = whole(v, 1, 1_000)?;
            Ok(())
        },
        redesign: false,
        ty: ParamType::U16,
        crtp: true,
        crazyflie_alias: "",
    },
    real!("PD_X_P", "PD north loop, (m/s^2)/m", true, tuning.pd_position[0].kp),
    real!("PD_X_D", "PD north loop, (m/s^2)/(m/s)", true, tuning.pd_position[0].kd),
    real!("PD_Y_P", "PD east loop, (m/s^2)/m", true, tuning.pd_position[1].kp),
    real!("PD_Y_D", "PD east loop, (m/s^2)/(m/s)", true, tuning.pd_position[1].kd),
    real!("PD_Z_P", "PD down loop, (m/s^2)/m", true, tuning.pd_position[2].kp),
    real!("PD_Z_D", "PD down loop, (m/s^2)/(m/s)", true, tuning.pd_position[2].kd),
    real!(
        "PD_ROLL_P",
        "PD roll loop, (rad/s^2)/rad",
        true,
        tuning.pd_attitude[0].kp
    )
    .aliased("pid_attitude.roll_kp"),
    real!(
        "PD_ROLL_D",
        "PD roll loop, (rad/s^2)/(rad/s)",
        true,
        tuning.pd_attitude[0].kd
    )
    .aliased("pid_attitude.roll_kd"),
    real!(
        "PD_PITCH_P",
        "PD pitch loop, (rad/s^2)/rad",
        true,
        tuning.pd_attitude[1].kp
    )
    .aliased("pid_attitude.pitch_kp"),
    real!(
        "PD_PITCH_D",
        "PD pitch loop, (rad/s^2)/(rad/s)",
        true,
        tuning.pd_attitude[1].kd
    )
    .aliased("pid_attitude.pitch_kd"),
    real!("PD_YAW_P", "PD yaw loop, (rad/s^2)/rad", true, tuning.pd_attitude[2].kp).aliased("pid_attitude.yaw_kp"),
    real!(
        "PD_YAW_D",
        "PD yaw loop, (rad/s^2)/(rad/s)",
        true,
        tuning.pd_attitude[2].kd
    )
    .aliased("pid_attitude.yaw_kd"),
    real!(
        "LQR_W_POS",
        "LQR position weights, multiple of the preset's",
        true,
        tuning.lqr.position
    ),
    real!(
        "LQR_W_VEL",
        "LQR velocity weights, multiple of the preset's",
        true,
        tuning.lqr.velocity
    ),
    real!(
        "LQR_W_ATT",
        "LQR attitude weights, multiple of the preset's",
        true,
        tuning.lqr.attitude
    ),
    real!(
        "LQR_W_RATE",
        "LQR body-rate weights, multiple of the preset's",
        true,
        tuning.lqr.rate
    ),
    real!(
        "LQR_W_U",
        "LQR input weights, multiple of the preset's",
        true,
        tuning.lqr.input
    ),
    real!(
        "MPC_W_POS",
        "MPC position weights, multiple of the preset's",
        true,
        tuning.mpc.position
    ),
    real!(
        "MPC_W_VEL",
        "MPC velocity weights, multiple of the preset's",
        true,
        tuning.mpc.velocity
    ),
    real!(
        "MPC_W_ATT",
        "MPC attitude weights, multiple of the preset's",
        true,
        tuning.mpc.attitude
    ),
    real!(
        "MPC_W_RATE",
        "MPC body-rate weights, multiple of the preset's",
        true,
        tuning.mpc.rate
    ),
    real!(
        "MPC_W_U",
        "MPC input weights, multiple of the preset's",
        true,
        tuning.mpc.input
    ),
    real!(
        "MPC_W_DU",
        "MPC input-rate weights, multiple of the preset's",
        true,
        tuning.mpc.input_rate
    ),
    real!(
        "MPC_OBS_M_TAU",
        "MPC moment-disturbance estimate time constant, s (0 preset)",
        true,
        tuning.mpc_moment_tau_s
    ), // The automatic modes (PX4's names; MAVLink only).
    nav!(
        "MIS_TAKEOFF_ALT",
        "takeoff height above home, m",
        0.2,
        100.0,
        takeoff_alt_m
    ),
    nav!(
        "RTL_RETURN_ALT",
        "least height of a return home, m",
        0.2,
        500.0,
        rtl_alt_m
    ),
    nav!(
        "MPC_XY_CRUISE",
        "horizontal speed of the automatic modes, m/s",
        0.1,
        20.0,
        cruise_mps
    ),
    nav!(
        "MPC_Z_V_AUTO_UP",
        "climb speed of the automatic modes, m/s",
        0.1,
        8.0,
        climb_mps
    ),
    nav!("MPC_LAND_SPEED", "descent speed of a landing, m/s", 0.1, 4.0, land_mps),
    nav!(
        "COM_OF_LOSS_T",
        "offboard set-points silent this long end offboard, s",
        0.1,
        60.0,
        offboard_loss_s
    ),
    nav!(
        "NAV_ACC_RAD",
        "a mission waypoint is reached within this, m",
        0.01,
        100.0,
        acc_rad_m
    ),
    nav!(
        "MPC_VEL_MANUAL",
        "horizontal speed of a full joystick deflection, m/s",
        0.1,
        20.0,
        manual_mps
    ),
    nav!(
        "MPC_Z_VEL_MAX_UP",
        "vertical speed of full joystick throttle, m/s",
        0.1,
        8.0,
        manual_z_mps
    ),
    nav!(
        "MPC_MAN_Y_MAX",
        "heading rate of a full yaw deflection, deg/s",
        1.0,
        400.0,
        manual_yaw_dps
    ),
    nav!(
        "COM_RC_LOSS_T",
        "a joystick silent this long is lost (then land), s",
        0.1,
        60.0,
        manual_loss_s
    ),
    Param {
        id: "SYS_FAILURE_EN",
        doc: "failure injection (MAV_CMD_INJECT_FAILURE) obeyed, 0/1",
        get: |s| f32::from(u8::from(s.nav.failure_injection)),
        set: |s, v| {
            s.nav.failure_injection = whole(v, 0, 1)? == 1;
            Ok(())
        },
        redesign: false,
        ty: ParamType::U8,
        crtp: false,
        crazyflie_alias: "",
    },
];

/// How many of [`PARAMS`] CRTP serves: the first ones (its param TOC's
/// ids are their indexes); none after them is served.
pub const CRTP_PARAMS: usize = {
    let mut n = 0;
    while n < PARAMS.len() && PARAMS[n].crtp {
        n += 1;
    }
    let mut i = n;
    while i < PARAMS.len() {
        assert!(!PARAMS[i].crtp, "CRTP's parameters come first");
        i += 1;
    }
    n
};

/// The parameters CRTP serves, the first [`CRTP_PARAMS`] of [`PARAMS`]
/// (their CRTP ids are their indexes).
pub fn crtp_params() -> &'static [Param] {
    &PARAMS[..CRTP_PARAMS]
}

/// How many of [`PARAMS`] CRTP serves under a Crazyflie name too
/// ([`Param::crtp_alias`]).
pub const CRTP_ALIASES: usize = {
    let mut n = 0;
    let mut i = 0;
    while i < PARAMS.len() {
        let a = PARAMS[i].crazyflie_alias.as_bytes();
        if !a.is_empty() {
            assert!(PARAMS[i].crtp, "an alias is CRTP's");
            // `group.name`: one dot, neither part empty.
            let mut dots = 0;
            let mut k = 0;
            while k < a.len() {
                if a[k] == b'.' {
                    assert!(k > 0 && k + 1 < a.len(), "an alias is group.name");
                    dots += 1;
                }
                k += 1;
            }
            assert!(dots == 1, "an alias is group.name");
            n += 1;
        }
        i += 1;
    }
    n
};

/// The indexes of the parameters CRTP serves under a Crazyflie name too,
/// in table order: CRTP's param TOC lists them after [`CRTP_PARAMS`].
pub const CRTP_ALIASED: [usize; CRTP_ALIASES] = {
    let mut out = [0; CRTP_ALIASES];
    let (mut n, mut i) = (0, 0);
    while i < PARAMS.len() {
        if !PARAMS[i].crazyflie_alias.is_empty() {
            out[n] = i;
            n += 1;
        }
        i += 1;
    }
    out
};

/// The index of the parameter named `id` (a MAVLink `param_id`: up to 16
/// bytes, NUL-padded when shorter).
pub fn index_of(id: &[u8]) -> Option<usize> {
    let len = id.iter().position(|&b| b == 0).unwrap_or(id.len());
    PARAMS.iter().position(|p| p.id.as_bytes() == &id[..len])
}

/// The parameters whose value in `s` differs from `base` (e.g. the boot
/// settings), as `(index, parameter, value in s)`: what a host writes to
/// make a flight controller booted with `base` fly `s`.
pub fn differences<'a>(s: &'a Settings, base: &'a Settings) -> impl Iterator<Item = (usize, &'static Param, f32)> + 'a {
    PARAMS.iter().enumerate().filter_map(move |(i, p)| {
        let value = (p.get)(s);
        (value.to_bits() != (p.get)(base).to_bits()).then_some((i, p, value))
    })
}

/// Writes parameter `index` = `value` into a copy of `s` and checks the
/// copy; the new settings, or why not.
pub fn write(s: &Settings, index: usize, value: f32) -> Result<Settings, Refusal> {
    let mut next = *s;
    write_into(&mut next, index, value)?;
    Ok(next)
}

/// Writes parameter `index` = `value` into `next` and checks it as a
/// whole; the mixer the check built ([`Settings::checked_mixer`]), or why
/// not (`next` is then not to be used). In place: a write under a lock
/// copies no settings it does not need to.
pub fn write_into(next: &mut Settings, index: usize, value: f32) -> Result<Mixer<f32>, Refusal> {
    let p = PARAMS.get(index).ok_or(Refusal::Unknown)?;
    (p.set)(next, value)?;
    next.checked_mixer()
}
