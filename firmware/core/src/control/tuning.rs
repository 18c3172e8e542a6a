//! The gains and weights a user may change on a flying vehicle: the
//! flight controller's `PD_*`, `LQR_W_*` and `MPC_W_*` parameters.
//!
//! [`Tuning`] holds them in units that mean the same on every vehicle, so a
//! set tuned on one airframe is a sensible start on another:
//!
//! - **PD**: the position loops command an acceleration, (m/s²)/m and
//!   (m/s²)/(m/s); the attitude loops command an *angular* acceleration per
//!   rad of attitude error and per rad/s of rate error, (rad/s²)/rad and
//!   (rad/s²)/(rad/s). The controllers' own gains (N/rad for U2, U3; N·m/rad
//!   for U4; per quaternion unit in the quaternion form, where the error is
//!   about half the angle) follow from the vehicle's inertia and arm:
//!   [`PdEulerGains::from_tuning`], [`PdQuatGains::from_tuning`]. One set
//!   serves both forms.
//! - **LQR and MPC**: multipliers of the preset's state and input weights,
//!   by group (position, velocity, attitude, body rate, input; the MPC also
//!   its input-rate weight). All 1 is the preset. Weights are relative: the
//!   multipliers say what to care about more, not how fast to be.
//! - **MPC moment observer**: its time constant, s (0: the preset's).
//!
//! [`Tuning::project`] is the project's preset (`tuned` PD gains, the
//! weights unchanged); [`super::ControllerSpec::build`] uses it, so the
//! study and a flight controller at its default parameters fly the same
//! controller.

use super::{MpcConfig, PdAxis, PdEulerGains, PdQuatGains};
use crate::model::VehicleParams;
use nalgebra::{RealField, SMatrix};

/// Multipliers of an LQR's or MPC's diagonal weights, by group of the
/// state `(x, y, z, ẋ, ẏ, ż, attitude ×3, p, q, r)` and of the input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeightScale {
    /// Position error (x, y, z, NED).
    pub position: f32,
    /// Velocity error (NED).
    pub velocity: f32,
    /// Attitude error (Euler angles or quaternion vector part).
    pub attitude: f32,
    /// Body-rate error (p, q, r, FRD).
    pub rate: f32,
    /// Input `U − U_ref` (U1 … U4).
    pub input: f32,
    /// Input rate `U_k − U_{k−1}` (MPC only; the LQR has no such weight).
    pub input_rate: f32,
}

impl WeightScale {
    /// Every multiplier 1: the preset's weights.
    pub const ONE: Self = Self {
        position: 1.0,
        velocity: 1.0,
        attitude: 1.0,
        rate: 1.0,
        input: 1.0,
        input_rate: 1.0,
    };

    /// The multiplier of state `i`'s weight (`i` in 0..12).
    fn state(&self, i: usize) -> f64 {
        f64::from(match i / 3 {
            0 => self.position,
            1 => self.velocity,
            2 => self.attitude,
            _ => self.rate,
        })
    }

    /// Scales an LQR's weights `q` (12 × 12) and `r` (4 × 4) in place.
    pub fn apply_lqr(&self, q: &mut SMatrix<f64, 12, 12>, r: &mut SMatrix<f64, 4, 4>) {
        for i in 0..12 {
            q[(i, i)] *= self.state(i);
        }
        *r *= f64::from(self.input);
    }

    /// Scales an MPC configuration's weights in place.
    fn apply_mpc(&self, cfg: &mut MpcConfig) {
        for (i, q) in cfg.q.iter_mut().enumerate() {
            *q *= self.state(i);
        }
        cfg.r.iter_mut().for_each(|r| *r *= f64::from(self.input));
        cfg.s.iter_mut().for_each(|s| *s *= f64::from(self.input_rate));
    }
}

/// The user's gains and weights (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tuning {
    /// PD position loops x, y, z (NED): (m/s²)/m, (m/s²)/(m/s).
    pub pd_position: [PdAxis<f32>; 3],
    /// PD attitude loops roll, pitch, yaw (body FRD): (rad/s²)/rad,
    /// (rad/s²)/(rad/s).
    pub pd_attitude: [PdAxis<f32>; 3],
    /// Multipliers of the LQR's weights.
    pub lqr: WeightScale,
    /// Multipliers of the MPC's weights.
    pub mpc: WeightScale,
    /// Time constant of the MPC's moment-disturbance estimate, s (0: the
    /// preset's, [`MpcConfig::observer_moment_tau_s`]). The fast preset's
    /// 4 ms makes up for slow rotors on the OS4 and flies rotorpy's
    /// Crazyflie and Hummingbird as it is.
    pub mpc_moment_tau_s: f32,
}

/// Inertia per unit of input lever for roll, pitch, yaw: `Ix/l`, `Iy/l`
/// (kg·m, U2 and U3 act at the arm `l`) and `Iz` (kg·m², U4 is a moment).
/// An angular-acceleration gain times this is the gain in input units.
fn input_per_angular_accel<T: RealField + Copy>(p: &VehicleParams<T>) -> [T; 3] {
    [
        p.inertia_kgm2[0] / p.arm_m,
        p.inertia_kgm2[1] / p.arm_m,
        p.inertia_kgm2[2],
    ]
}

impl Tuning {
    /// The project's preset: the `tuned` Euler PD's gains
    /// ([`PdEulerGains::tuned`]) as the accelerations they command on the
    /// OS4, and the LQR's and MPC's weights unchanged.
    pub fn project() -> Self {
        let g = PdEulerGains::<f64>::tuned();
        let k = input_per_angular_accel(&VehicleParams::<f64>::os4());
        let f = |a: PdAxis<f64>, k: f64| PdAxis {
            kp: (a.kp / k) as f32,
            kd: (a.kd / k) as f32,
        };
        Self {
            pd_position: [f(g.x, 1.0), f(g.y, 1.0), f(g.z, 1.0)],
            pd_attitude: [f(g.roll, k[0]), f(g.pitch, k[1]), f(g.yaw, k[2])],
            lqr: WeightScale::ONE,
            mpc: WeightScale::ONE,
            mpc_moment_tau_s: 0.0,
        }
    }

    /// An MPC configuration with this tuning applied: weights scaled, and
    /// the moment observer's time constant replaced unless it is 0.
    pub fn apply_mpc(&self, cfg: &mut MpcConfig) {
        self.mpc.apply_mpc(cfg);
        if self.mpc_moment_tau_s != 0.0 {
            cfg.observer_moment_tau_s = f64::from(self.mpc_moment_tau_s);
        }
    }
}

impl Default for Tuning {
    fn default() -> Self {
        Self::project()
    }
}

/// `a` in `T`, both gains times `k`.
fn axis<T: RealField + Copy>(a: PdAxis<f32>, kp: T, kd: T) -> PdAxis<T> {
    PdAxis {
        kp: T::from_subset(&f64::from(a.kp)) * kp,
        kd: T::from_subset(&f64::from(a.kd)) * kd,
    }
}

impl<T: RealField + Copy> PdEulerGains<T> {
    /// The Euler PD's gains for vehicle `p` from the tuning's accelerations.
    pub fn from_tuning(t: &Tuning, p: &VehicleParams<T>) -> Self {
        let k = input_per_angular_accel(p);
        let [x, y, z] = t.pd_position.map(|a| axis(a, T::one(), T::one()));
        Self {
            x,
            y,
            z,
            roll: axis(t.pd_attitude[0], k[0], k[0]),
            pitch: axis(t.pd_attitude[1], k[1], k[1]),
            yaw: axis(t.pd_attitude[2], k[2], k[2]),
        }
    }
}

impl<T: RealField + Copy> PdQuatGains<T> {
    /// The quaternion PD's gains for vehicle `p` from the tuning's
    /// accelerations: the quaternion error's vector part is half the angle
    /// for small errors, so its proportional gains are twice the Euler
    /// form's (the rate gains are the same).
    pub fn from_tuning(t: &Tuning, p: &VehicleParams<T>) -> Self {
        let k = input_per_angular_accel(p);
        let two = T::one() + T::one();
        let [x, y, z] = t.pd_position.map(|a| axis(a, T::one(), T::one()));
        Self {
            x,
            y,
            z,
            q1: axis(t.pd_attitude[0], two * k[0], k[0]),
            q2: axis(t.pd_attitude[1], two * k[1], k[1]),
            q3: axis(t.pd_attitude[2], two * k[2], k[2]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-6 * b.abs().max(1.0)
    }

    /// The project's tuning gives the hand-tuned gains of both PD forms on
    /// the OS4 (to f32 rounding): the Euler form's `tuned()`, and the
    /// quaternion form's `tuned()`, which was derived by hand from it.
    #[test]
    fn project_tuning_is_the_tuned_pd_of_both_forms() {
        let p = VehicleParams::<f64>::os4();
        let t = Tuning::project();
        let (e, e0) = (PdEulerGains::from_tuning(&t, &p), PdEulerGains::<f64>::tuned());
        let (q, q0) = (PdQuatGains::from_tuning(&t, &p), PdQuatGains::<f64>::tuned());
        let pairs = [
            (e.x, e0.x),
            (e.y, e0.y),
            (e.z, e0.z),
            (e.roll, e0.roll),
            (e.pitch, e0.pitch),
            (e.yaw, e0.yaw),
            (q.x, q0.x),
            (q.y, q0.y),
            (q.z, q0.z),
            (q.q1, q0.q1),
            (q.q2, q0.q2),
            (q.q3, q0.q3),
        ];
        for (a, b) in pairs {
            assert!(close(a.kp, b.kp) && close(a.kd, b.kd), "{a:?} vs {b:?}");
        }
        // The roll loop's natural frequency on the OS4 (thesis' torque l·U2):
        // ωn² = l·Kp/Ix is the tuning's own number, ≈ 15 rad/s.
        let wn = libm::sqrt(f64::from(t.pd_attitude[0].kp));
        assert!((14.0..16.0).contains(&wn), "{wn}");
    }

    /// An attitude gain in angular acceleration commands the same angular
    /// acceleration on any vehicle: a vehicle with 4× the inertia and twice
    /// the arm gets twice the roll gain in N/rad (and 3× Iz, 3× yaw).
    #[test]
    fn attitude_gains_command_the_same_angular_acceleration_on_any_vehicle() {
        let (os4, p) = (
            VehicleParams::<f64>::os4(),
            super::super::pd_euler::gain_scale_tests::bigger_os4(),
        );
        let t = Tuning::project();
        let (a, b) = (PdEulerGains::from_tuning(&t, &os4), PdEulerGains::from_tuning(&t, &p));
        assert!(close(b.roll.kp, 2.0 * a.roll.kp) && close(b.pitch.kd, 2.0 * a.pitch.kd));
        assert!(close(b.yaw.kp, 3.0 * a.yaw.kp) && close(b.yaw.kd, 3.0 * a.yaw.kd));
        let alpha = |g: &PdEulerGains<f64>, v: &VehicleParams<f64>| v.arm_m * g.roll.law(0.1, -0.3) / v.inertia_kgm2[0];
        assert!(close(alpha(&b, &p), alpha(&a, &os4)));
        // And it is the tuning's number: 0.1 rad, −0.3 rad/s.
        let k = t.pd_attitude[0];
        assert!(close(alpha(&a, &os4), f64::from(k.kp) * 0.1 - f64::from(k.kd) * 0.3));
    }

    /// The multipliers scale their group's weights and nothing else; all 1
    /// leaves the weights bit for bit.
    #[test]
    fn weight_multipliers_scale_their_group_only() {
        let base = MpcConfig::fast(crate::model::AttitudeForm::Quaternion);
        let mut same = base;
        WeightScale::ONE.apply_mpc(&mut same);
        assert_eq!(same, base);
        let w = WeightScale {
            velocity: 2.0,
            input_rate: 0.5,
            ..WeightScale::ONE
        };
        let mut c = base;
        w.apply_mpc(&mut c);
        for i in 0..12 {
            let k = if (3..6).contains(&i) { 2.0 } else { 1.0 };
            assert_eq!(c.q[i], k * base.q[i], "q[{i}]");
        }
        assert_eq!(c.r, base.r);
        assert_eq!(c.s, base.s.map(|s| 0.5 * s));
        let (mut q, mut r) = (SMatrix::<f64, 12, 12>::identity(), SMatrix::<f64, 4, 4>::identity());
        WeightScale {
            attitude: 3.0,
            input: 4.0,
            ..WeightScale::ONE
        }
        .apply_lqr(&mut q, &mut r);
        assert_eq!(q[(7, 7)], 3.0);
        assert_eq!(q[(9, 9)], 1.0);
        assert_eq!(r, SMatrix::<f64, 4, 4>::identity() * 4.0);
    }
}
