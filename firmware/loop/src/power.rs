//! The stabilizer step's last two stages, the Crazyflie's `supervisor` gate
//! and `power_distribution`: whether the motors run this step, and the
//! rotor thrusts and motor commands of the inputs that fly.
//!
//! What decides the gate is the vehicle's supervisor: armed, in a mode or
//! under a set-point that flies, not tumbled ([`crate::supervisor`], [`crate::modes`],
//! [`crate::commander`]). The mixer is the one the [`Loop`]'s settings give
//! ([`Loop::mixer`]), built when a protocol front end starts
//! ([`start_front_end`](crate::start_front_end)) and again whenever a
//! parameter changes the settings.

use crate::Loop;
use fc_core::model::airframe::{Mixer, MotorCommands};
use nalgebra::Vector4;

/// What the motors get from one stabilizer step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Power {
    /// The inputs applied `[U1 N, U2 N, U3 N, U4 N·m]`: the controller's,
    /// or zero when the motors are off.
    pub u: Vector4<f32>,
    /// Each rotor's thrust that realises `u`, N, motor 1 to 4 (negative
    /// where `u` is not reachable; zero when the motors are off).
    pub thrusts_n: Vector4<f32>,
    /// The motor commands, in the mixer's unit, each rotor's speed clamped
    /// to `[0, Ωmax]` (zero when the motors are off).
    pub motors: MotorCommands<f32>,
    /// The motors run: the supervisor let the step fly and the vehicle has
    /// a mixer.
    pub on: bool,
}

impl Power {
    /// Motors off: zero inputs, thrusts and commands.
    pub const OFF: Self = Self {
        u: Vector4::new(0.0, 0.0, 0.0, 0.0),
        thrusts_n: Vector4::new(0.0, 0.0, 0.0, 0.0),
        motors: MotorCommands {
            commands: [0.0; 4],
            clamped: false,
        },
        on: false,
    };
}

/// The supervisor's gate and the mixer: the inputs `u` (`None`: the
/// controller gave none) flown through `mixer` when `fly` (the supervisor
/// lets this step fly) and there is a mixer; [`Power::OFF`] otherwise.
pub fn distribute(mixer: Option<&Mixer<f32>>, fly: bool, u: Option<[f32; 4]>) -> Power {
    match (mixer, u) {
        (Some(m), Some(u)) if fly => {
            let u = Vector4::from(u);
            let thrusts_n = m.thrusts(&u);
            Power {
                u,
                thrusts_n,
                motors: m.commands_for(&thrusts_n),
                on: true,
            }
        }
        // Armed with no inputs: the motors run at zero.
        (Some(_), None) if fly => Power { on: true, ..Power::OFF },
        _ => Power::OFF,
    }
}

impl Loop {
    /// The mixer of the settings in force (`None` until a protocol front
    /// end starts the loop, [`start_front_end`](crate::start_front_end)).
    pub fn mixer(&self) -> Option<&Mixer<f32>> {
        self.mixer.as_ref()
    }

    /// The step's inputs `u` (`None`: none) through the supervisor's gate
    /// `fly` and the mixer in force ([`distribute`]).
    pub fn power(&self, fly: bool, u: Option<[f32; 4]>) -> Power {
        distribute(self.mixer.as_ref(), fly, u)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fc_core::model::airframe::{MotorUnit, RotorLayout};
    use fc_core::VehicleParams;

    fn mixer() -> Mixer<f32> {
        let p = VehicleParams::<f32>::os4();
        Mixer::new(&RotorLayout::plus(p.arm_m), &p, MotorUnit::ThrustFraction).unwrap()
    }

    #[test]
    fn hover_thrust_is_shared_by_the_four_rotors() {
        // Analytic: U1 alone on a plus layout is a quarter per rotor, and
        // a thrust fraction is that over kf·Ωmax².
        let p = VehicleParams::<f32>::os4();
        let m = mixer();
        let u1 = p.hover_thrust_n();
        let pw = distribute(Some(&m), true, Some([u1, 0.0, 0.0, 0.0]));
        let f_max = p.kf_ns2 * p.omega_max_radps * p.omega_max_radps;
        assert!(pw.on);
        for i in 0..4 {
            assert!((pw.thrusts_n[i] - u1 / 4.0).abs() < 1e-5 * u1, "{pw:?}");
            assert!((pw.motors.commands[i] - u1 / 4.0 / f_max).abs() < 1e-5, "{pw:?}");
        }
        assert!(!pw.motors.clamped);
    }

    #[test]
    fn the_gate_holds_the_motors_off() {
        let m = mixer();
        let u = Some([6.0, 0.1, 0.0, 0.0]);
        assert_eq!(distribute(Some(&m), false, u), Power::OFF);
        assert_eq!(distribute(None, true, u), Power::OFF, "no mixer: not started");
        let idle = distribute(Some(&m), true, None);
        assert!(idle.on && idle.motors.commands == [0.0; 4] && idle.u == Vector4::zeros());
    }

    #[test]
    fn the_mixer_follows_the_settings() {
        use crate::params;
        let mut fl = crate::FlightLoop::unstarted(crate::FcConfig::default());
        assert!(fl.split().0.mixer().is_none(), "no mixer before the start");
        fl.start_front_end().unwrap();
        let before = *fl.split().0.mixer().unwrap();
        let i = params::index_of(b"MOT_HUB_M").unwrap();
        let v = (params::PARAMS[i].get)(fl.split().0.settings());
        fl.apply_param(i, v * 2.0, false).unwrap();
        let after = *fl.split().0.mixer().unwrap();
        assert_ne!(before, after, "a new arm length is a new mixer");
        assert_eq!(Some(&after), fl.split().0.settings().mixer().ok().as_ref());
    }
}
