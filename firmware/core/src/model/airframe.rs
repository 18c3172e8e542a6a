//! Motor outputs for any quadrotor airframe: where each rotor is, which way
//! it spins, and how the motor command is expressed (PX4's mixer idea).
//!
//! The controllers produce the thesis' inputs `U = [U1 N, U2 N, U3 N, U4 N·m]`
//! (docs/book/src/model.md §3): total thrust, the roll and pitch force differences
//! (moments `l·U2`, `l·U3` with `l` = [`VehicleParams::arm_m`]) and the yaw
//! moment. [`Mixer`] turns them into one command per motor for a
//! [`RotorLayout`] — the OS4's "+" of the thesis, an "X" such as the
//! Crazyflie's, any four rotors in the body plane — in the [`MotorUnit`] the
//! motors (or a simulator) expect. The allocation is exact when every rotor
//! is inside `[0, Ωmax]`; otherwise each command is clamped and the output
//! says so.

use super::{lit, VehicleParams};
use nalgebra::{Matrix4, RealField, Vector4};

/// Which way a rotor turns, seen from above.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Spin {
    /// Clockwise from above: its drag turns the body anticlockwise (a
    /// negative yaw moment about body z, FRD down).
    Clockwise,
    /// Anticlockwise from above: a positive yaw moment on the body.
    Anticlockwise,
}

impl Spin {
    /// The sign of the yaw moment (about body z, FRD) this rotor's drag puts on the body.
    fn yaw_sign<T: RealField + Copy>(self) -> T {
        match self {
            Spin::Clockwise => -T::one(),
            Spin::Anticlockwise => T::one(),
        }
    }
}

/// One rotor: its hub in the body plane and its spin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rotor<T> {
    /// Hub position (x forward, y right), body FRD, m, from the centre of mass.
    pub pos_frd_m: [T; 2],
    /// Which way it turns.
    pub spin: Spin,
}

/// Four rotors in motor order (the order of the motor commands).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RotorLayout<T> {
    /// Motor 1 to 4.
    pub rotors: [Rotor<T>; 4],
}

impl<T: RealField + Copy> RotorLayout<T> {
    /// The thesis' OS4 "+" (docs/book/src/model.md §3): motor 1 front, 2 right, 3
    /// rear, 4 left, at `arm_m`; 1 and 3 anticlockwise, 2 and 4 clockwise —
    /// the layout [`super::mix`] assumes.
    pub fn plus(arm_m: T) -> Self {
        let z = T::zero();
        let (a, c) = (Spin::Anticlockwise, Spin::Clockwise);
        Self::from_hubs([[arm_m, z], [z, arm_m], [-arm_m, z], [z, -arm_m]], [a, c, a, c])
    }

    /// An "X" with hubs `hub_m` from the centre at 45° in rotorpy's motor
    /// order (its Crazyflie model): 1 front-left clockwise, 2 front-right
    /// anticlockwise, 3 rear-right clockwise, 4 rear-left anticlockwise.
    pub fn x_rotorpy(hub_m: T) -> Self {
        let h = hub_m / lit::<T>(2.0).sqrt();
        let (a, c) = (Spin::Anticlockwise, Spin::Clockwise);
        Self::from_hubs([[h, -h], [h, h], [-h, h], [-h, -h]], [c, a, c, a])
    }

    /// PX4's quadrotor X (its airframe reference, "Quadrotor x"; also
    /// ArduPilot's Quad X): 1 front-right anticlockwise, 2 rear-left
    /// anticlockwise, 3 front-left clockwise, 4 rear-right clockwise, hubs
    /// `hub_m` from the centre at 45°.
    pub fn x_px4(hub_m: T) -> Self {
        let h = hub_m / lit::<T>(2.0).sqrt();
        let (a, c) = (Spin::Anticlockwise, Spin::Clockwise);
        Self::from_hubs([[h, h], [-h, -h], [h, -h], [-h, h]], [a, a, c, c])
    }

    /// Betaflight's Quad X with its default ("props in") directions: 1
    /// rear-right clockwise, 2 front-right anticlockwise, 3 rear-left
    /// anticlockwise, 4 front-left clockwise (`MOT_REV` 15 gives "props out").
    pub fn x_betaflight(hub_m: T) -> Self {
        let h = hub_m / lit::<T>(2.0).sqrt();
        let (a, c) = (Spin::Anticlockwise, Spin::Clockwise);
        Self::from_hubs([[-h, h], [h, h], [-h, -h], [h, -h]], [c, a, a, c])
    }

    /// The Crazyflie 2.x as its firmware numbers it: M1 front-right
    /// anticlockwise, M2 rear-right clockwise, M3 rear-left anticlockwise,
    /// M4 front-left clockwise.
    pub fn x_crazyflie(hub_m: T) -> Self {
        let h = hub_m / lit::<T>(2.0).sqrt();
        let (a, c) = (Spin::Anticlockwise, Spin::Clockwise);
        Self::from_hubs([[h, h], [-h, h], [-h, -h], [h, -h]], [a, c, a, c])
    }

    /// Motors 1 to 4 at the hub positions `pos_frd_m` (x forward, y right,
    /// m) with the spins `spin`.
    pub fn from_hubs(pos_frd_m: [[T; 2]; 4], spin: [Spin; 4]) -> Self {
        Self {
            rotors: core::array::from_fn(|i| Rotor {
                pos_frd_m: pos_frd_m[i],
                spin: spin[i],
            }),
        }
    }

    /// The wrench `[thrust N, Mx, My, Mz N·m]` (body FRD) of rotor thrusts
    /// `f` (N, along −z): rows `1`, `−y`, `x`, `±kM/kf`.
    pub fn effectiveness(&self, km_over_kf_m: T) -> Matrix4<T> {
        Matrix4::from_fn(|row, i| {
            let r = &self.rotors[i];
            match row {
                0 => T::one(),
                1 => -r.pos_frd_m[1],
                2 => r.pos_frd_m[0],
                _ => r.spin.yaw_sign::<T>() * km_over_kf_m,
            }
        })
    }
}

/// How a motor command is expressed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotorUnit {
    /// Rotor speed as a fraction of Ωmax, in [0, 1] (PX4's HIL motor
    /// outputs as rotorpy and jMAVSim read them).
    SpeedFraction,
    /// Rotor thrust as a fraction of its largest (`kf·Ωmax²`), in [0, 1].
    ThrustFraction,
    /// An ESC pulse, µs, linear in rotor speed from `min_us` (stopped) to
    /// `max_us` (Ωmax).
    PwmUs {
        /// Pulse at zero speed, µs.
        min_us: u16,
        /// Pulse at Ωmax, µs.
        max_us: u16,
    },
}

/// Why a mixer cannot be built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MixerError {
    /// The layout cannot produce every wrench (its effectiveness matrix is
    /// singular: rotors on one line, all spinning one way, …).
    Singular,
    /// A parameter the mixer needs is not finite and positive (named).
    Parameter(&'static str),
    /// A PWM range whose maximum is not above its minimum.
    PwmRange,
}

impl core::fmt::Display for MixerError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            MixerError::Singular => write!(f, "the rotor layout cannot produce every thrust and moment (singular)"),
            MixerError::Parameter(p) => write!(f, "mixer parameter {p} must be finite and positive"),
            MixerError::PwmRange => write!(f, "the PWM range's maximum must be above its minimum"),
        }
    }
}

/// One command per motor, in the mixer's [`MotorUnit`], and whether any was clamped.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotorCommands<T> {
    /// Motor 1 to 4.
    pub commands: [T; 4],
    /// A rotor needed a speed outside `[0, Ωmax]` (or the input was not finite).
    pub clamped: bool,
}

/// Inputs `U` → motor commands for one airframe (precomputed allocation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mixer<T> {
    /// Wrench → rotor thrusts.
    allocation: Matrix4<T>,
    arm_m: T,
    kf: T,
    omega_max: T,
    unit: MotorUnit,
}

impl<T: RealField + Copy> Mixer<T> {
    /// The mixer of `layout` on a vehicle `p` (its `kf`, `kM`, `Ωmax` and
    /// the arm `l` of `U2`, `U3`), commanding in `unit`.
    pub fn new(layout: &RotorLayout<T>, p: &VehicleParams<T>, unit: MotorUnit) -> Result<Self, MixerError> {
        let positive = |v: T| v.is_finite() && v > T::zero();
        for (name, v) in [
            ("kf_ns2", p.kf_ns2),
            ("km_nms2", p.km_nms2),
            ("omega_max_radps", p.omega_max_radps),
            ("arm_m", p.arm_m),
        ] {
            if !positive(v) {
                return Err(MixerError::Parameter(name));
            }
        }
        if layout.rotors.iter().flat_map(|r| r.pos_frd_m).any(|v| !v.is_finite()) {
            return Err(MixerError::Parameter("pos_frd_m"));
        }
        if let MotorUnit::PwmUs { min_us, max_us } = unit {
            if max_us <= min_us {
                return Err(MixerError::PwmRange);
            }
        }
        let allocation = layout
            .effectiveness(p.km_nms2 / p.kf_ns2)
            .try_inverse()
            .filter(|m| m.iter().all(|v| v.is_finite()))
            .ok_or(MixerError::Singular)?;
        Ok(Self {
            allocation,
            arm_m: p.arm_m,
            kf: p.kf_ns2,
            omega_max: p.omega_max_radps,
            unit,
        })
    }

    /// Rotor thrusts (N) that realise `u` exactly (negative where `u` is not reachable).
    pub fn thrusts(&self, u: &Vector4<T>) -> Vector4<T> {
        let wrench = Vector4::new(u[0], self.arm_m * u[1], self.arm_m * u[2], u[3]);
        self.allocation * wrench
    }

    /// The motor commands for `u`, each rotor's speed clamped to `[0, Ωmax]`
    /// (a non-finite input commands zero and is reported as clamped).
    pub fn commands(&self, u: &Vector4<T>) -> MotorCommands<T> {
        self.commands_for(&self.thrusts(u))
    }

    /// The motor commands for the rotor thrusts `f` (N, as
    /// [`Mixer::thrusts`] gives them), as [`Mixer::commands`] clamps them.
    pub fn commands_for(&self, f: &Vector4<T>) -> MotorCommands<T> {
        let f_max = self.kf * self.omega_max * self.omega_max;
        let mut clamped = false;
        let commands = core::array::from_fn(|i| {
            let fi = f[i];
            let thrust_frac = if fi.is_finite() { fi / f_max } else { T::zero() };
            let frac = if thrust_frac < T::zero() || !fi.is_finite() {
                clamped = true;
                T::zero()
            } else if thrust_frac > T::one() {
                clamped = true;
                T::one()
            } else {
                thrust_frac
            };
            match self.unit {
                MotorUnit::ThrustFraction => frac,
                MotorUnit::SpeedFraction => frac.sqrt(),
                MotorUnit::PwmUs { min_us, max_us } => {
                    let (lo, hi) = (lit::<T>(f64::from(min_us)), lit::<T>(f64::from(max_us)));
                    lo + (hi - lo) * frac.sqrt()
                }
            }
        });
        MotorCommands { commands, clamped }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::unmix;

    /// rotorpy's Crazyflie (`rotorpy.vehicles.crazyflie_params`): 30 g,
    /// kf 2.3e-8, kM 7.8e-10, Ωmax 2500 rad/s, hubs 43 mm from the centre.
    fn crazyflie() -> VehicleParams<f64> {
        VehicleParams {
            mass_kg: 0.03,
            inertia_kgm2: [1.43e-5, 1.43e-5, 2.89e-5],
            arm_m: 0.043,
            kf_ns2: 2.3e-8,
            km_nms2: 7.8e-10,
            omega_max_radps: 2500.0,
            ..VehicleParams::OS4
        }
    }

    #[test]
    fn the_plus_layout_is_the_thesis_mixer() {
        let p = VehicleParams::<f64>::OS4;
        let m = Mixer::new(&RotorLayout::plus(p.arm_m), &p, MotorUnit::ThrustFraction).unwrap();
        for u in [
            Vector4::new(6.4, 0.0, 0.0, 0.0),
            Vector4::new(7.0, 0.3, -0.2, 0.01),
            Vector4::new(5.0, -1.0, 0.5, -0.02),
        ] {
            let want = unmix(&p, &u) * p.kf_ns2;
            assert!((m.thrusts(&u) - want).amax() < 1e-12, "{u}");
        }
    }

    #[test]
    fn the_x_layout_allocates_as_rotorpy_does() {
        // rotorpy: `Multirotor(quad_params).TM_to_f @ [0.3, 1e-3, 2e-3, 1e-4]`
        // (thrust N and moments N·m about its body FLU axes) in its motor
        // order; in FRD the y and z moments change sign.
        let rotorpy = [0.06751501, 0.0495963, 0.08395935, 0.09892934];
        let p = crazyflie();
        let m = Mixer::new(&RotorLayout::x_rotorpy(0.043), &p, MotorUnit::ThrustFraction).unwrap();
        let l = p.arm_m;
        let f = m.thrusts(&Vector4::new(0.3, 1e-3 / l, -2e-3 / l, -1e-4));
        for (a, b) in f.iter().zip(rotorpy) {
            assert!((a - b).abs() < 1e-7, "{f} vs {rotorpy:?}");
        }
    }

    #[test]
    fn thrusts_produce_the_commanded_moments() {
        // Moments from first principles (r × F, F along −z; drag moment ∓kM·Ω²).
        let p = crazyflie();
        let layout = RotorLayout::x_rotorpy(0.043);
        let m = Mixer::new(&layout, &p, MotorUnit::SpeedFraction).unwrap();
        let u = Vector4::new(0.35, 0.01, -0.02, 2e-5);
        let f = m.thrusts(&u);
        let (mut t, mut mx, mut my, mut mz) = (0.0, 0.0, 0.0, 0.0);
        for (r, fi) in layout.rotors.iter().zip(f.iter()) {
            let [x, y] = r.pos_frd_m;
            t += fi;
            // (x, y, 0) × (0, 0, −f) = (−y·f, x·f, 0).
            mx += -y * fi;
            my += x * fi;
            let spin = if r.spin == Spin::Anticlockwise { 1.0 } else { -1.0 };
            mz += spin * p.km_nms2 / p.kf_ns2 * fi;
        }
        let got = [t, mx, my, mz];
        let want = [u[0], p.arm_m * u[1], p.arm_m * u[2], u[3]];
        for (g, w) in got.iter().zip(want) {
            assert!((g - w).abs() < 1e-12, "{got:?} vs {want:?}");
        }
    }

    /// Every standard layout reproduces every wrench: the thrusts the mixer
    /// asks for, put back through first principles (r × F, drag moments),
    /// give the commanded thrust and moments.
    #[test]
    fn every_layout_reproduces_each_wrench() {
        let p = crazyflie();
        let layouts = [
            ("plus", RotorLayout::plus(0.043)),
            ("rotorpy", RotorLayout::x_rotorpy(0.043)),
            ("px4", RotorLayout::x_px4(0.043)),
            ("betaflight", RotorLayout::x_betaflight(0.043)),
            ("crazyflie", RotorLayout::x_crazyflie(0.043)),
        ];
        for (name, layout) in layouts {
            let m = Mixer::new(&layout, &p, MotorUnit::SpeedFraction).unwrap();
            for u in [
                Vector4::new(0.3, 0.0, 0.0, 0.0),
                Vector4::new(0.35, 0.01, -0.02, 2e-5),
                Vector4::new(0.25, -0.03, 0.0, 0.0),
                Vector4::new(0.3, 0.0, 0.025, -4e-5),
            ] {
                let f = m.thrusts(&u);
                let mut w = [0.0; 4];
                for (r, fi) in layout.rotors.iter().zip(f.iter()) {
                    let [x, y] = r.pos_frd_m;
                    let spin = if r.spin == Spin::Anticlockwise { 1.0 } else { -1.0 };
                    w[0] += fi;
                    w[1] += -y * fi;
                    w[2] += x * fi;
                    w[3] += spin * p.km_nms2 / p.kf_ns2 * fi;
                }
                let want = [u[0], p.arm_m * u[1], p.arm_m * u[2], u[3]];
                for (g, wnt) in w.iter().zip(want) {
                    assert!((g - wnt).abs() < 1e-12, "{name}: {u}: {w:?} vs {want:?}");
                }
            }
        }
    }

    /// Which motors speed up for a pure moment, as each vendor numbers its
    /// motors (PX4's airframe reference, Betaflight's motor tab, the
    /// Crazyflie's firmware): roll right (left side up), pitch up (nose
    /// up), yaw right (clockwise from above: the anticlockwise rotors).
    #[test]
    fn each_vendors_motor_numbering_and_spins() {
        let p = crazyflie();
        let faster = |layout: &RotorLayout<f64>, u: Vector4<f64>| -> [bool; 4] {
            let m = Mixer::new(layout, &p, MotorUnit::ThrustFraction).unwrap();
            let hover = m.thrusts(&Vector4::new(0.3, 0.0, 0.0, 0.0));
            let f = m.thrusts(&u);
            core::array::from_fn(|i| f[i] > hover[i])
        };
        let roll = Vector4::new(0.3, 0.02, 0.0, 0.0);
        let pitch = Vector4::new(0.3, 0.0, 0.02, 0.0);
        let yaw = Vector4::new(0.3, 0.0, 0.0, 5e-5);
        // PX4: 1 front-right, 2 rear-left, 3 front-left, 4 rear-right; 1, 2 anticlockwise.
        let px4 = RotorLayout::x_px4(0.043);
        assert_eq!(faster(&px4, roll), [false, true, true, false]);
        assert_eq!(faster(&px4, pitch), [true, false, true, false]);
        assert_eq!(faster(&px4, yaw), [true, true, false, false]);
        // Betaflight: 1 rear-right, 2 front-right, 3 rear-left, 4 front-left; 2, 3 anticlockwise.
        let bf = RotorLayout::x_betaflight(0.043);
        assert_eq!(faster(&bf, roll), [false, false, true, true]);
        assert_eq!(faster(&bf, pitch), [false, true, false, true]);
        assert_eq!(faster(&bf, yaw), [false, true, true, false]);
        // Crazyflie: M1 front-right, M2 rear-right, M3 rear-left, M4 front-left; M1, M3 anticlockwise.
        let cf = RotorLayout::x_crazyflie(0.043);
        assert_eq!(faster(&cf, roll), [false, false, true, true]);
        assert_eq!(faster(&cf, pitch), [true, false, false, true]);
        assert_eq!(faster(&cf, yaw), [true, false, true, false]);
    }

    #[test]
    fn hover_commands_in_each_unit() {
        let p = crazyflie();
        let layout = RotorLayout::x_rotorpy(0.043);
        let hover = Vector4::new(0.03 * 9.81, 0.0, 0.0, 0.0);
        // Ω_hover = √(m·g / 4kf) = 1785.7 rad/s: 71.4 % of Ωmax, 51.0 % of the thrust.
        let speed = (0.03 * 9.81 / (4.0 * 2.3e-8_f64)).sqrt() / 2500.0;
        for (unit, want) in [
            (MotorUnit::SpeedFraction, speed),
            (MotorUnit::ThrustFraction, speed * speed),
            (
                MotorUnit::PwmUs {
                    min_us: 1000,
                    max_us: 2000,
                },
                1000.0 + 1000.0 * speed,
            ),
        ] {
            let c = Mixer::new(&layout, &p, unit).unwrap().commands(&hover);
            assert!(!c.clamped);
            assert!(c.commands.iter().all(|v| (v - want).abs() < 1e-9), "{unit:?}: {c:?}");
        }
    }

    #[test]
    fn unreachable_or_corrupt_inputs_are_clamped_and_reported() {
        let p = crazyflie();
        let m = Mixer::new(&RotorLayout::x_rotorpy(0.043), &p, MotorUnit::SpeedFraction).unwrap();
        let c = m.commands(&Vector4::new(2.0, 0.0, 0.0, 0.0));
        assert!(c.clamped && c.commands == [1.0; 4], "{c:?}");
        let c = m.commands(&Vector4::new(0.3, 5.0, 0.0, 0.0));
        assert!(c.clamped && c.commands.contains(&0.0), "{c:?}");
        let c = m.commands(&Vector4::new(f64::NAN, 0.0, 0.0, 0.0));
        assert!(c.clamped && c.commands == [0.0; 4], "{c:?}");
    }

    #[test]
    fn impossible_airframes_are_refused_with_a_reason() {
        let p = crazyflie();
        let mut same_spin = RotorLayout::x_rotorpy(0.043);
        for r in &mut same_spin.rotors {
            r.spin = Spin::Clockwise;
        }
        assert_eq!(
            Mixer::new(&same_spin, &p, MotorUnit::SpeedFraction),
            Err(MixerError::Singular)
        );
        let bad = VehicleParams { kf_ns2: 0.0, ..p };
        let e = Mixer::new(&RotorLayout::x_rotorpy(0.043), &bad, MotorUnit::SpeedFraction).unwrap_err();
        assert_eq!(e, MixerError::Parameter("kf_ns2"));
        assert!(e.to_string().contains("kf_ns2"));
        let pwm = MotorUnit::PwmUs {
            min_us: 2000,
            max_us: 1000,
        };
        assert_eq!(
            Mixer::new(&RotorLayout::x_rotorpy(0.043), &p, pwm),
            Err(MixerError::PwmRange)
        );
    }
}
