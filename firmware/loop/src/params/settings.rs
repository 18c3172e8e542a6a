//! What the parameters set ([`Settings`]) and its check as a whole.

use super::{NavSettings, Refusal};
use fc_core::control::{ControllerSpec, Tuning};
use fc_core::model::airframe::{Mixer, MotorUnit, RotorLayout, Spin};
use fc_core::model::VehicleParams;

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
    /// has been seen) → land where it is, ms; 0: off. Default 10 s, PX4's
    /// `COM_DL_LOSS_T`: a ground station that beats at 1 Hz over a link
    /// losing 30 % of its datagrams misses 5 in a row too often for 5 s.
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
            gcs_loss_ms: 10_000,
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
        self.checked_mixer().map(|_| ())
    }

    /// [`Settings::check`], returning the mixer the check built: a write
    /// that is taken flies it, and builds no other.
    pub fn checked_mixer(&self) -> Result<Mixer<f32>, Refusal> {
        self.vehicle.check().map_err(|e| Refusal::Range {
            lo: e.range.lo as f32,
            hi: e.range.hi as f32,
        })?;
        // Built where it is returned, not moved out and back: a write
        // checks under the link's lock (the refusals' order is kept).
        let mixer = self.mixer();
        mixer.as_ref().map_err(|&e| e)?;
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
        check_tuning(&self.tuning)?;
        mixer
    }
}

/// `v` in `[lo, hi]` (NaN is not).
pub(super) fn within(v: f32, lo: f32, hi: f32) -> Result<(), Refusal> {
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
