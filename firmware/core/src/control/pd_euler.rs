//! PD controller, Euler form: trajectory mode (thesis 3.83–3.86) on top of
//! attitude mode (3.75–3.79). Gains: thesis Tables 4.1–4.2.

use super::{
    observer::AccelObserver, reference::tilt_and_thrust, validate, wrap_pi, AttitudeRef, ControlError, ControlOutput,
    Controller, ReferenceMode, Setpoint, StateEstimate,
};
use crate::lit;
use crate::math as trig;
use crate::model::{InputBox, Vehicle, VehicleParams};
use nalgebra::{RealField, Vector3, Vector4};

/// Proportional and derivative gain of one loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdAxis<T> {
    /// Proportional gain.
    pub kp: T,
    /// Derivative gain.
    pub kd: T,
}

impl<T: RealField + Copy> PdAxis<T> {
    /// From `f64` gains.
    pub fn new(kp: f64, kd: f64) -> Self {
        Self {
            kp: lit(kp),
            kd: lit(kd),
        }
    }

    /// `kp·e + kd·ė`.
    #[inline]
    pub fn law(&self, e: T, e_dot: T) -> T {
        self.kp * e + self.kd * e_dot
    }

    /// Both gains times `k`.
    pub fn scaled(&self, k: T) -> Self {
        Self {
            kp: self.kp * k,
            kd: self.kd * k,
        }
    }
}

/// How much larger the attitude gains of `p` must be than the OS4's for
/// the same closed-loop attitude dynamics: the angular acceleration of a
/// roll or pitch input `U` is `l·U/I`, of a yaw input `U4/Iz`, so the
/// gains scale as `I/l` (roll, pitch) and `Iz` (yaw). Exactly 1 on the
/// OS4 (`(x/y)/(x/y)`), so the thesis' and project's gains are unchanged
/// there. The position loops give accelerations and need no scaling.
pub fn attitude_gain_scale<T: RealField + Copy>(p: &VehicleParams<T>) -> [T; 3] {
    let os4 = VehicleParams::<T>::os4();
    let lever = |p: &VehicleParams<T>, i: usize| p.inertia_kgm2[i] / p.arm_m;
    [
        lever(p, 0) / lever(&os4, 0),
        lever(p, 1) / lever(&os4, 1),
        p.inertia_kgm2[2] / os4.inertia_kgm2[2],
    ]
}

/// Gains of the Euler PD controller. Position loops give accelerations
/// (m/s² per m, per m/s); attitude loops give U2, U3 (N per rad, per rad/s)
/// and U4 (N·m per rad, per rad/s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PdEulerGains<T> {
    /// x loop.
    pub x: PdAxis<T>,
    /// y loop.
    pub y: PdAxis<T>,
    /// z loop (3.78).
    pub z: PdAxis<T>,
    /// Roll loop (3.75).
    pub roll: PdAxis<T>,
    /// Pitch loop (3.76).
    pub pitch: PdAxis<T>,
    /// Yaw loop (3.77).
    pub yaw: PdAxis<T>,
}

impl<T: RealField + Copy> PdEulerGains<T> {
    /// Thesis Tables 4.1 (x 2.1/2.8, y 2.15/2.5, z 7.495/5, ψ 5/1.4) and 4.2
    /// (θ 2.1/2.8, φ 2.15/2.5).
    pub fn thesis() -> Self {
        Self {
            x: PdAxis::new(2.1, 2.8),
            y: PdAxis::new(2.15, 2.5),
            z: PdAxis::new(7.495, 5.0),
            roll: PdAxis::new(2.15, 2.5),
            pitch: PdAxis::new(2.1, 2.8),
            yaw: PdAxis::new(5.0, 1.4),
        }
    }

    /// These gains for vehicle `p` ([`attitude_gain_scale`]): the same
    /// attitude dynamics as on the OS4.
    pub fn for_vehicle(&self, p: &VehicleParams<T>) -> Self {
        let [kr, kp, ky] = attitude_gain_scale(p);
        Self {
            roll: self.roll.scaled(kr),
            pitch: self.pitch.scaled(kp),
            yaw: self.yaw.scaled(ky),
            ..*self
        }
    }

    /// The project's default: the thesis gains except roll and pitch.
    ///
    /// Table 4.2 repeats Table 4.1's x/y gains for θ/φ. With torques `l·U2`
    /// they give `θ̈ = 64.5(θd − θ) − 99.3 θ̇`, an attitude pole at −0.65 rad/s,
    /// and the x cascade `1.53s³ + 1.24s² + 2.95s + 2.1` is barely stable
    /// (Routh margin 3.65 vs 3.21): the vehicle never settles. Here roll and
    /// pitch are placed at ωn ≈ 15 rad/s, ten times faster than the position
    /// loops (Kp 7.3 N/rad), and damped for the rotors: Kd 1.0 N·s/rad
    /// (ζ ≈ 1.5 without rotor lag). With the vehicle's 0.178 s rotor lag a
    /// lighter Kd (0.45, ζ ≈ 0.9 on paper) loses the loop once the rotational
    /// drag is half the nominal and the inertia 30 % higher: the sweep's
    /// corner, where the Routh condition of `(Is² + k_r s)(τs + 1) + l(K_d s +
    /// K_p)` fails (docs/book/src/model.md §8.6). x, y, z and ψ keep the thesis gains (z
    /// and ψ reproduce the thesis' settling times).
    pub fn tuned() -> Self {
        Self {
            roll: PdAxis::new(7.3, 1.0),
            pitch: PdAxis::new(7.3, 1.0),
            ..Self::thesis()
        }
    }
}

/// The Euler PD controller.
#[derive(Debug, Clone)]
pub struct PdEuler<T: RealField + Copy> {
    vehicle: Vehicle<T>,
    gains: PdEulerGains<T>,
    mode: ReferenceMode,
    bx: InputBox<T>,
    obs: AccelObserver<T>,
}

impl<T: RealField + Copy> PdEuler<T> {
    /// A controller for the vehicle `params` (the controller's model).
    pub fn new(params: VehicleParams<T>, gains: PdEulerGains<T>, mode: ReferenceMode) -> Self {
        Self {
            bx: params.input_box(),
            vehicle: Vehicle::new(&params),
            gains,
            mode,
            obs: AccelObserver::off(),
        }
    }

    /// The same with integral action: the disturbance observer `obs`
    /// ([`AccelObserver`]) whose estimate the position loops cancel.
    pub fn with_observer(mut self, obs: AccelObserver<T>) -> Self {
        self.obs = obs;
        self
    }

    /// The disturbance observer (off for the thesis gains).
    pub fn observer(&self) -> &AccelObserver<T> {
        &self.obs
    }
}

/// Desired acceleration of the trajectory loops (3.78, 3.83, 3.84), with the
/// reference acceleration added in feed-forward mode.
pub(crate) fn desired_accel<T: RealField + Copy>(
    gx: &PdAxis<T>,
    gy: &PdAxis<T>,
    gz: &PdAxis<T>,
    est: &StateEstimate<T>,
    sp: &Setpoint<T>,
    mode: ReferenceMode,
) -> Vector3<T> {
    let e = sp.pos_ned_m - est.pos_ned_m;
    let ed = sp.vel_ned_mps - est.vel_ned_mps;
    let fb = Vector3::new(gx.law(e[0], ed[0]), gy.law(e[1], ed[1]), gz.law(e[2], ed[2]));
    match mode {
        ReferenceMode::Thesis => fb,
        ReferenceMode::Feedforward => fb + sp.acc_ned_mps2,
    }
}

impl<T: RealField + Copy> Controller<T> for PdEuler<T> {
    fn update(&mut self, est: &StateEstimate<T>, sp: &Setpoint<T>) -> Result<ControlOutput<T>, ControlError> {
        validate(est, sp)?;
        let g = &self.gains;
        self.obs.observe(est);
        let acc = desired_accel(&g.x, &g.y, &g.z, est, sp, self.mode) - self.obs.estimate();
        let e = est.euler();
        let (phi, theta, psi) = (e[0], e[1], e[2]);
        // Desired tilt from the desired acceleration at the current heading (3.85, 3.86).
        let tt = tilt_and_thrust(&self.vehicle.params, &acc, &est.vel_ned_mps, psi);
        // Euler angle rates from body rates.
        let w = est.rates_frd_radps;
        let (sphi, cphi) = trig::sin_cos(phi);
        let (sth, cth) = trig::sin_cos(theta);
        let cth = cth.max(lit(0.1));
        let tth = sth / cth;
        let phi_dot = w[0] + (w[1] * sphi + w[2] * cphi) * tth;
        let theta_dot = w[1] * cphi - w[2] * sphi;
        let psi_dot = (w[1] * sphi + w[2] * cphi) / cth;
        // Desired Euler rates: the feed-forward attitude's (body rates ≈ Euler
        // rates at the small tilts where the feed-forward matters).
        let wd = match self.mode {
            ReferenceMode::Thesis => Vector3::zeros(),
            ReferenceMode::Feedforward => AttitudeRef::feedforward(&self.vehicle.params, sp).rates_frd_radps,
        };
        // Thrust with tilt and drag compensation at the actual attitude (3.79).
        let tilt_cos = (cphi * trig::cos(theta)).max(lit(0.5));
        let tff = self.obs.torque_feedforward(&self.vehicle);
        let lift = tt.thrust_n * trig::cos(tt.roll_rad) * trig::cos(tt.pitch_rad);
        let raw = Vector4::new(
            lift / tilt_cos,
            g.roll.law(tt.roll_rad - phi, wd[0] - phi_dot) + tff[0],
            g.pitch.law(tt.pitch_rad - theta, wd[1] - theta_dot) + tff[1],
            g.yaw.law(wrap_pi(sp.yaw_rad - psi), wd[2] - psi_dot) + tff[2],
        );
        Ok(self.obs.finish(&self.bx, &self.vehicle, est, &raw))
    }

    fn reset(&mut self) {
        self.obs.reset();
    }

    fn elapsed(&mut self, dt_s: T) {
        self.obs.elapsed(dt_s);
    }

    fn resume(&mut self) {
        self.obs.resume();
    }
}

#[cfg(test)]
pub(crate) mod gain_scale_tests {
    use super::*;

    /// The OS4 with inertia ×4 about x and y, ×3 about z and the arm ×2:
    /// its attitude gains in input units are ×2 (roll, pitch) and ×3 (yaw).
    pub(crate) fn bigger_os4() -> VehicleParams<f64> {
        let os4 = VehicleParams::<f64>::os4();
        let mut p = os4;
        p.inertia_kgm2 = [
            4.0 * os4.inertia_kgm2[0],
            4.0 * os4.inertia_kgm2[1],
            3.0 * os4.inertia_kgm2[2],
        ];
        p.arm_m = 2.0 * os4.arm_m;
        p
    }

    #[test]
    fn attitude_gains_keep_the_os4s_angular_dynamics_on_another_vehicle() {
        // Exactly the OS4's gains on the OS4 (the study is unchanged).
        assert_eq!(attitude_gain_scale(&VehicleParams::<f64>::os4()), [1.0; 3]);
        assert_eq!(attitude_gain_scale(&VehicleParams::<f32>::os4()), [1.0; 3]);
        assert_eq!(
            PdEulerGains::<f32>::tuned().for_vehicle(&VehicleParams::os4()),
            PdEulerGains::tuned()
        );
        // Inertia ×4 about x and y, ×3 about z, arm ×2: roll and pitch
        // gains ×2 (I/l), yaw ×3 (Iz); the position loops unchanged.
        let (os4, p) = (VehicleParams::<f64>::os4(), bigger_os4());
        let k = attitude_gain_scale(&p);
        assert!(
            (k[0] - 2.0).abs() < 1e-12 && (k[1] - 2.0).abs() < 1e-12 && (k[2] - 3.0).abs() < 1e-12,
            "{k:?}"
        );
        // The angular acceleration a roll error commands, l·U2/I, is the OS4's.
        let (g0, g) = (
            PdEulerGains::<f64>::tuned(),
            PdEulerGains::<f64>::tuned().for_vehicle(&p),
        );
        let alpha = |g: &PdEulerGains<f64>, v: &VehicleParams<f64>| v.arm_m * g.roll.law(0.1, -0.3) / v.inertia_kgm2[0];
        assert!((alpha(&g, &p) - alpha(&g0, &os4)).abs() < 1e-12);
        assert_eq!((g.x, g.y, g.z), (g0.x, g0.y, g0.z));
    }
}
