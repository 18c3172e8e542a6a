//! The flight controller's parameters, as MAVLink's parameter protocol
//! (PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET / PARAM_VALUE), a
//! ground station and our own protocol (`ParamSet`/`ParamRead` → `Param`) see them: one table, [`PARAMS`], of named values, each
//! with its unit, how to read and write it in [`Settings`], and whether a
//! change re-designs the controller (allowed only while disarmed).
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

use fc_core::control::ControlError;
use fc_core::control::{ControllerSpec, SpecError, Tuning};
use fc_core::model::airframe::{Mixer, MixerError, MotorUnit, RotorLayout, Spin};
use fc_core::model::VehicleParams;

pub use crate::modes::NavSettings;

/// The rotor layouts a parameter can choose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Airframe {
    /// The thesis' OS4 "+" ([`RotorLayout::plus`]): `MOT_FRAME` 0.
    Plus,
    /// An "X" in rotorpy's (and its Crazyflie's) motor order
    /// ([`RotorLayout::x_rotorpy`]): `MOT_FRAME` 1.
    XRotorpy,
    /// PX4's quadrotor X ([`RotorLayout::x_px4`]): `MOT_FRAME` 2.
    XPx4,
    /// Betaflight's Quad X, props in ([`RotorLayout::x_betaflight`]): `MOT_FRAME` 3.
    XBetaflight,
    /// The Crazyflie 2.x's M1–M4 ([`RotorLayout::x_crazyflie`]): `MOT_FRAME` 4.
    XCrazyflie,
}

impl Airframe {
    /// Every layout, in `MOT_FRAME` order.
    pub const ALL: [Airframe; 5] = [
        Airframe::Plus,
        Airframe::XRotorpy,
        Airframe::XPx4,
        Airframe::XBetaflight,
        Airframe::XCrazyflie,
    ];
}

/// Everything the parameters set: the vehicle, its motors, the controller
/// and the failsafe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Settings {
    /// The vehicle the controller is designed for (and the mixer uses).
    pub vehicle: VehicleParams<f32>,
    /// Where the rotors are, in motor order.
    pub airframe: Airframe,
    /// Distance of each hub from the centre, m.
    pub hub_m: f32,
    /// Motors whose spin is the reverse of the airframe's (bit i: motor i+1).
    pub reversed: u8,
    /// What a motor command means.
    pub unit: MotorUnit,
    /// The controller.
    pub controller: ControllerSpec,
    /// Its gains and weights (`PD_*`, `LQR_W_*`, `MPC_W_*`).
    pub tuning: Tuning,
    /// No valid sensor step (`HIL_SENSOR`, or our protocol's `Sensor`/`Imu`)
    /// for this long → failsafe, ms; the loop never uses less than two
    /// periods of the running controller.
    pub failsafe_timeout_ms: u32,
    /// Failsafe thrust as a fraction of hover thrust (below 1: descend).
    pub failsafe_descent: f32,
    /// No ground-station `HEARTBEAT` for this long while armed (once one
    /// has been seen) → land where it is, ms; 0: off.
    pub gcs_loss_ms: u32,
    /// Period of the position fixes taken from `HIL_STATE_QUATERNION`, ms.
    pub fix_period_ms: u32,
    /// The automatic modes' settings ([`crate::modes`]).
    pub nav: NavSettings,
}

impl Settings {
    /// The OS4 of the thesis on its "+" frame, motor speeds as fractions,
    /// the boot controller (quaternion LQR), failsafe after 50 ms without
    /// sensor data (85 % of hover thrust), fixes at 100 Hz.
    pub fn os4() -> Self {
        let vehicle = VehicleParams::<f32>::os4();
        Self {
            vehicle,
            airframe: Airframe::Plus,
            hub_m: vehicle.arm_m,
            reversed: 0,
            unit: MotorUnit::SpeedFraction,
            controller: crate::BOOT_CONTROLLER,
            tuning: Tuning::project(),
            failsafe_timeout_ms: 50,
            failsafe_descent: 0.85,
            gcs_loss_ms: 5_000,
            fix_period_ms: 10,
            nav: NavSettings::default(),
        }
    }

    /// The rotors in motor order, with `reversed` applied.
    pub fn layout(&self) -> RotorLayout<f32> {
        let mut l = match self.airframe {
            Airframe::Plus => RotorLayout::plus(self.hub_m),
            Airframe::XRotorpy => RotorLayout::x_rotorpy(self.hub_m),
            Airframe::XPx4 => RotorLayout::x_px4(self.hub_m),
            Airframe::XBetaflight => RotorLayout::x_betaflight(self.hub_m),
            Airframe::XCrazyflie => RotorLayout::x_crazyflie(self.hub_m),
        };
        for (i, r) in l.rotors.iter_mut().enumerate() {
            if self.reversed & (1 << i) != 0 {
                r.spin = match r.spin {
                    Spin::Clockwise => Spin::Anticlockwise,
                    Spin::Anticlockwise => Spin::Clockwise,
                };
            }
        }
        l
    }

    /// The mixer these settings give.
    pub fn mixer(&self) -> Result<Mixer<f32>, Refusal> {
        Mixer::new(&self.layout(), &self.vehicle, self.unit).map_err(Refusal::Mixer)
    }

    /// Checks the settings as a whole (see the module's documentation).
    pub fn check(&self) -> Result<(), Refusal> {
        self.vehicle.check().map_err(|e| Refusal::Range {
            lo: e.range.lo as f32,
            hi: e.range.hi as f32,
        })?;
        self.mixer()?;
        if !(10..=5_000).contains(&self.failsafe_timeout_ms) {
            return Err(Refusal::Range { lo: 10.0, hi: 5_000.0 });
        }
        within(self.failsafe_descent, 0.5, 1.0)?;
        if self.gcs_loss_ms != 0 && !(500..=60_000).contains(&self.gcs_loss_ms) {
            return Err(Refusal::Range {
                lo: 500.0,
                hi: 60_000.0,
            });
        }
        if !(1..=1_000).contains(&self.fix_period_ms) {
            return Err(Refusal::Range { lo: 1.0, hi: 1_000.0 });
        }
        check_tuning(&self.tuning)
    }
}

/// `v` in `[lo, hi]` (NaN is not).
fn within(v: f32, lo: f32, hi: f32) -> Result<(), Refusal> {
    if v >= lo && v <= hi {
        Ok(())
    } else {
        Err(Refusal::Range { lo, hi })
    }
}

/// The gains' and weights' ranges: PD position gains in [0, 100]
/// ((m/s²)/m, (m/s²)/(m/s)), attitude gains in [0, 10⁴] ((rad/s²)/rad,
/// (rad/s²)/(rad/s)); weight multipliers in [10⁻³, 10³]; the MPC's moment
/// observer 0 (the preset's) or in [10⁻³, 10] s.
fn check_tuning(t: &Tuning) -> Result<(), Refusal> {
    for a in t.pd_position {
        within(a.kp, 0.0, 100.0)?;
        within(a.kd, 0.0, 100.0)?;
    }
    for a in t.pd_attitude {
        within(a.kp, 0.0, 1e4)?;
        within(a.kd, 0.0, 1e4)?;
    }
    if t.mpc_moment_tau_s != 0.0 {
        within(t.mpc_moment_tau_s, 1e-3, 10.0)?;
    }
    for w in [t.lqr, t.mpc] {
        for m in [w.position, w.velocity, w.attitude, w.rate, w.input, w.input_rate] {
            within(m, 1e-3, 1e3)?;
        }
    }
    Ok(())
}

/// Why a parameter write was refused (each short enough for a 50-character
/// `STATUSTEXT` after the parameter's name).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Refusal {
    /// No parameter has this name (or index).
    Unknown,
    /// The value is outside `[lo, hi]` (or not finite).
    Range {
        /// Smallest accepted.
        lo: f32,
        /// Largest accepted.
        hi: f32,
    },
    /// An integer-valued parameter was given a fraction.
    NotInteger,
    /// The controller id names no controller of this firmware.
    Controller(SpecError),
    /// The motors cannot be mixed with these settings.
    Mixer(MixerError),
    /// The controller could not be designed for the new settings.
    Design(ControlError),
    /// The change re-designs the controller: only while disarmed.
    Armed,
    /// A re-design is under way (in the controller's task): write again
    /// once it is answered.
    Busy,
}

impl Refusal {
    /// Its code in our protocol's `Param` answer (0 there: not refused).
    pub fn code(&self) -> u8 {
        match self {
            Refusal::Unknown => 1,
            Refusal::Range { .. } => 2,
            Refusal::NotInteger => 3,
            Refusal::Controller(_) => 4,
            Refusal::Mixer(_) => 5,
            Refusal::Design(_) => 6,
            Refusal::Armed => 7,
            Refusal::Busy => 8,
        }
    }
}

impl core::fmt::Display for Refusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Refusal::Unknown => f.write_str("no such parameter"),
            Refusal::Range { lo, hi } => write!(f, "out of [{}, {}]", Num(*lo), Num(*hi)),
            Refusal::NotInteger => f.write_str("must be a whole number"),
            Refusal::Controller(_) => f.write_str("no controller has this id"),
            Refusal::Mixer(MixerError::Singular) => f.write_str("rotor layout is singular"),
            Refusal::Mixer(MixerError::PwmRange) => f.write_str("PWM max must exceed min"),
            Refusal::Mixer(MixerError::Parameter(_)) => f.write_str("mixer needs a positive value"),
            Refusal::Design(_) => f.write_str("controller design failed"),
            Refusal::Armed => f.write_str("disarm first"),
            Refusal::Busy => f.write_str("a re-design is under way"),
        }
    }
}

/// A number in at most six significant digits (`0.01`, `100`, `-1`,
/// `1.5e-7`), written with integer formatting only: `f32`'s own `Display`
/// links ≈ 20 KiB of float-printing code into the image for a few
/// `STATUSTEXT`s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f32);

impl core::fmt::Display for Num {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let x = self.0;
        if x.is_nan() {
            return f.write_str("NaN");
        }
        if x < 0.0 {
            f.write_str("-")?;
        }
        let a = libm::fabsf(x);
        if a.is_infinite() {
            return f.write_str("inf");
        }
        if a == 0.0 {
            return f.write_str("0");
        }
        // a = m · 10^e with m in [1, 10); plain notation for e in [-3, 6).
        let mut e = libm::floorf(libm::log10f(a)) as i32;
        let scaled = |e: i32| f64::from(a) / libm::pow(10.0, f64::from(e));
        // Six significant digits: an integer in [100 000, 1 000 000).
        let mut n = libm::round(scaled(e) * 1e5) as u64;
        if n >= 1_000_000 {
            e += 1;
            n = libm::round(scaled(e) * 1e5) as u64;
        }
        let (mut digits, mut len) = ([0u8; 6], 6);
        for d in digits.iter_mut().rev() {
            *d = b'0' + (n % 10) as u8;
            n /= 10;
        }
        while len > 1 && digits[len - 1] == b'0' {
            len -= 1;
        }
        let d = |i: usize| if i < len { digits[i] as char } else { '0' };
        let plain = (-3..6).contains(&e);
        if !plain {
            write!(f, "{}", d(0))?;
            if len > 1 {
                f.write_str(".")?;
                (1..len).try_for_each(|i| write!(f, "{}", d(i)))?;
            }
            return write!(f, "e{e}");
        }
        if e < 0 {
            f.write_str("0.")?;
            (0..(-e - 1)).try_for_each(|_| f.write_str("0"))?;
            return (0..len).try_for_each(|i| write!(f, "{}", d(i)));
        }
        let int_digits = e as usize + 1;
        (0..int_digits).try_for_each(|i| write!(f, "{}", d(i)))?;
        if len > int_digits {
            f.write_str(".")?;
            (int_digits..len).try_for_each(|i| write!(f, "{}", d(i)))?;
        }
        Ok(())
    }
}

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
        self.crtp.then(|| self.id.split_once('_').unwrap_or(("fc", self.id)))
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
pub const PARAMS: [Param; 63] = [
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
    ),
    real!(
        "PD_ROLL_D",
        "PD roll loop, (rad/s^2)/(rad/s)",
        true,
        tuning.pd_attitude[0].kd
    ),
    real!(
        "PD_PITCH_P",
        "PD pitch loop, (rad/s^2)/rad",
        true,
        tuning.pd_attitude[1].kp
    ),
    real!(
        "PD_PITCH_D",
        "PD pitch loop, (rad/s^2)/(rad/s)",
        true,
        tuning.pd_attitude[1].kd
    ),
    real!("PD_YAW_P", "PD yaw loop, (rad/s^2)/rad", true, tuning.pd_attitude[2].kp),
    real!(
        "PD_YAW_D",
        "PD yaw loop, (rad/s^2)/(rad/s)",
        true,
        tuning.pd_attitude[2].kd
    ),
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
    let p = PARAMS.get(index).ok_or(Refusal::Unknown)?;
    let mut next = *s;
    (p.set)(&mut next, value)?;
    next.check()?;
    Ok(next)
}
