//! The integral action of PD and LQR: a disturbance observer.
//!
//! Whatever the controller's model leaves out — wind, a heavier vehicle, a
//! weaker rotor, wrong drag, a moment from an off-centre load — shows up as
//! the difference between the acceleration the vehicle had and the one the
//! model ([`Vehicle`], docs/book/src/model.md §4) predicted for the input it was
//! sent. The observer low-passes that difference into estimates: `d̂` (NED,
//! m/s², the force part) and `m̂` (body FRD, rad/s², the moment part). The
//! controllers aim at the attitude and thrust that produce `a_ref − d̂`
//! and add the torques that cancel `m̂`, so constant disturbances leave no
//! steady offset: the offset-free principle of the MPC's observer.
//!
//! Per step, with `v`, `ω` the velocity and rate estimates, `dt` the
//! controller period and `u` the input sent the step before:
//!
//! ```text
//! r  = (v_k − v_{k−1})/dt − a_model(v_{k−1}, q_{k−1}, U1_{k−1})
//! d̂ ← d̂ + (dt/τ)·(r − d̂)                      (one stage: the PD)
//! d₁ ← d₁ + (2dt/τ)·(r − d₁), d̂ ← d̂ + (2dt/τ)·(d₁ − d̂)   (two: the LQR)
//! m̂ ← m̂ + (dt/τm)·((ω_k − ω_{k−1})/dt − ω̇_model(ω_{k−1}, u_{k−1}) − m̂)
//! ```
//!
//! each clamped per axis (±0.5 g, ±100 rad/s²). The velocity difference
//! carries the velocity noise at a gain of 1/dt, and one stage of τ passes
//! it as `σ_v/τ` of acceleration jitter. The LQR turns that into attitude
//! targets through large gains (with the report's noise × 2 it diverged), so
//! its force part is two stages of τ/2 ([`AccelObserver::smoothed`]), which
//! average the jitter down by ≈ √(dt/τ) for the same phase lag at a gust's
//! frequency. The PD keeps one stage: the extra lag of the second cost its
//! attitude loop the robustness sweep's worst corner.
//!
//! **Anti-windup by construction**: `u_{k−1}` is the input the controller
//! actually sent (after clamping into the input box), so when the box binds
//! the observer still compares the vehicle with the input it really got.
//! It never integrates a tracking error, so there is nothing to wind up: a
//! saturated climb does not leave an estimate that must be unwound
//! afterwards (a unit test holds the thrust at its limit for 6 s and finds
//! the estimate equal to the true disturbance).
//!
//! The time constants are the project's choice (docs/book/src/model.md §8.6): the
//! force part is fast (`τ` = 50 ms: a 0.5 Hz gust is mostly cancelled), the
//! moment part slow (`τm` = 1 s): with slow rotors the torque not yet
//! delivered looks like a moment disturbance, and a fast moment estimate
//! turned the PD's and LQR's attitude loops unstable on some of the
//! robustness sweep's vehicles.

use super::{ControlError, ControlOutput, StateEstimate};
use crate::lit;
use crate::model::{quat_to_rotation, Disturbance, Input, InputBox, Vehicle};
use nalgebra::{RealField, Vector3};

/// Largest disturbance the observer will believe, per NED axis, as a
/// fraction of g: ±0.5 g (a 3 m/s wind on the nominal vehicle is ≈ 0.06 g,
/// a 20 % mass error 0.2 g).
pub const DISTURBANCE_LIMIT_G: f64 = 0.5;

/// Largest angular-acceleration disturbance the observer will believe, per
/// body axis, rad/s² (the MPC's observer uses the same bound).
pub const MOMENT_LIMIT_RADPS2: f64 = 100.0;

/// What the observer remembers of the previous step: the velocity (NED m/s)
/// and body rates (FRD rad/s) then, and the accelerations the model
/// predicted from them for the input sent.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Pending<T: RealField + Copy> {
    vel_ned_mps: Vector3<T>,
    rates_frd_radps: Vector3<T>,
    model_acc_ned_mps2: Vector3<T>,
    model_rate_dot_frd_radps2: Vector3<T>,
}

/// A disturbance observer (see the module documentation): a force part
/// (NED acceleration) and a moment part (body angular acceleration), each
/// with its own time constant. `off()` gives one that always estimates zero
/// (the thesis' controllers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AccelObserver<T: RealField + Copy> {
    /// `dt/τ` of the force part's low-pass (one stage), or `dt/(τ/2)` of
    /// each of its two stages (0: off).
    gain: T,
    /// Two stages (see [`AccelObserver::smoothed`]).
    two_stage: bool,
    /// `dt/τ` of the moment part (0: off).
    gain_moment: T,
    /// `1/dt` of the nominal period, 1/s.
    inv_dt: T,
    /// The nominal period, s.
    period_s: f64,
    /// The measured interval the next update spans, s (`None`: the nominal
    /// period; see [`AccelObserver::elapsed`]).
    next_dt: Option<T>,
    /// Clamp on each axis of the force estimate, m/s².
    limit: T,
    /// The force part's first stage, NED m/s².
    d_stage: Vector3<T>,
    /// The force estimate (second stage), NED m/s².
    d_hat: Vector3<T>,
    /// The moment estimate, body FRD rad/s².
    m_hat: Vector3<T>,
    pending: Option<Pending<T>>,
}

impl<T: RealField + Copy> AccelObserver<T> {
    /// An observer that is not there: the estimates stay zero.
    pub fn off() -> Self {
        Self {
            gain: T::zero(),
            two_stage: false,
            gain_moment: T::zero(),
            inv_dt: T::zero(),
            period_s: 0.0,
            next_dt: None,
            limit: T::zero(),
            d_stage: Vector3::zeros(),
            d_hat: Vector3::zeros(),
            m_hat: Vector3::zeros(),
            pending: None,
        }
    }

    /// An observer with time constants `tau_s` (force) and `tau_moment_s`
    /// (moment) for a controller running every `period_s` (all s, finite,
    /// each `τ ≥ period_s > 0`), for a vehicle with gravity `gravity_mps2`.
    pub fn new(tau_s: f64, tau_moment_s: f64, period_s: f64, gravity_mps2: f64) -> Result<Self, ControlError> {
        let ok_tau = |t: f64| t.is_finite() && t >= period_s;
        let ok = period_s.is_finite() && period_s > 0.0 && ok_tau(tau_s) && ok_tau(tau_moment_s);
        if !(ok && gravity_mps2.is_finite() && gravity_mps2 > 0.0) {
            return Err(ControlError::InvalidParameter);
        }
        Ok(Self {
            gain: lit(period_s / tau_s),
            two_stage: false,
            gain_moment: lit(period_s / tau_moment_s),
            inv_dt: lit(1.0 / period_s),
            period_s,
            next_dt: None,
            limit: lit(DISTURBANCE_LIMIT_G * gravity_mps2),
            d_stage: Vector3::zeros(),
            d_hat: Vector3::zeros(),
            m_hat: Vector3::zeros(),
            pending: None,
        })
    }

    /// The same with the force part as two low-pass stages of τ/2 each
    /// instead of one of τ: the same phase lag at a gust's frequency, ≈ √(dt/τ)
    /// of the velocity noise it passes (see the module documentation).
    pub fn smoothed(mut self) -> Self {
        if self.is_on() && !self.two_stage {
            self.gain = (self.gain + self.gain).min(T::one());
            self.two_stage = true;
        }
        self
    }

    /// True unless built with [`AccelObserver::off`].
    pub fn is_on(&self) -> bool {
        self.gain > T::zero()
    }

    /// The current force estimate, NED m/s² (the acceleration the
    /// environment adds to what the model predicts).
    pub fn estimate(&self) -> Vector3<T> {
        self.d_hat
    }

    /// The current moment estimate, body FRD rad/s² (the angular
    /// acceleration the environment adds to what the model predicts).
    pub fn moment_estimate(&self) -> Vector3<T> {
        self.m_hat
    }

    /// The torque inputs `(U2 N, U3 N, U4 N·m)` that cancel the moment
    /// estimate on the vehicle `v` (zero when off).
    pub fn torque_feedforward(&self, v: &Vehicle<T>) -> Vector3<T> {
        let p = &v.params;
        Vector3::new(
            -p.inertia_kgm2[0] * self.m_hat[0] / p.arm_m,
            -p.inertia_kgm2[1] * self.m_hat[1] / p.arm_m,
            -p.inertia_kgm2[2] * self.m_hat[2],
        )
    }

    /// The next update spans `dt_s` (s, measured: [`crate::control::Controller::elapsed`])
    /// instead of the nominal period: its differences are taken over `dt_s`
    /// and its low-passes advance by `dt_s/τ` (at most 1). An implausible
    /// interval ([`super::plausible_step`]) is ignored.
    pub fn elapsed(&mut self, dt_s: T) {
        self.next_dt = super::plausible_step(dt_s, self.period_s).then_some(dt_s);
    }

    /// Updates the estimates with this step's velocity and rates (call
    /// first in a step).
    pub fn observe(&mut self, est: &StateEstimate<T>) {
        let dt = self.next_dt.take();
        let Some(prev) = self.pending.take() else { return };
        // The interval as a multiple of the nominal period (1 without a measurement).
        let s = dt.map_or(T::one(), |dt| dt * self.inv_dt);
        let inv_dt = self.inv_dt / s;
        let (gain, gain_moment) = ((self.gain * s).min(T::one()), (self.gain_moment * s).min(T::one()));
        let a_meas = (est.vel_ned_mps - prev.vel_ned_mps) * inv_dt;
        let mut d1 = self.d_stage + (a_meas - prev.model_acc_ned_mps2 - self.d_stage) * gain;
        let w_dot = (est.rates_frd_radps - prev.rates_frd_radps) * inv_dt;
        let mut m = self.m_hat + (w_dot - prev.model_rate_dot_frd_radps2 - self.m_hat) * gain_moment;
        let m_lim = lit::<T>(MOMENT_LIMIT_RADPS2);
        for i in 0..3 {
            d1[i] = d1[i].max(-self.limit).min(self.limit);
        }
        let mut d = if self.two_stage {
            self.d_hat + (d1 - self.d_hat) * gain
        } else {
            d1
        };
        for i in 0..3 {
            d[i] = d[i].max(-self.limit).min(self.limit);
            m[i] = m[i].max(-m_lim).min(m_lim);
        }
        // A non-finite innovation (cannot come from a validated estimate, but
        // costs nothing to refuse) leaves the estimates as they were.
        if d1.iter().chain(d.iter()).chain(m.iter()).all(|v| v.is_finite()) {
            self.d_stage = d1;
            self.d_hat = d;
            self.m_hat = m;
        }
    }

    /// Remembers what the model `v` predicts for the input `u` (the value
    /// sent, inside the box) at this step's estimate (call last in a step).
    pub fn record(&mut self, v: &Vehicle<T>, est: &StateEstimate<T>, u: &Input<T>) {
        if !self.is_on() {
            return;
        }
        let r = quat_to_rotation(&est.att);
        let col3 = Vector3::new(r[(0, 2)], r[(1, 2)], r[(2, 2)]);
        let none = Disturbance::none();
        self.pending = Some(Pending {
            vel_ned_mps: est.vel_ned_mps,
            rates_frd_radps: est.rates_frd_radps,
            model_acc_ned_mps2: v.accel(&est.vel_ned_mps, &col3, u[0], &none),
            // The rotors' gyroscopic term needs their speed, which the
            // controller does not know; it is small and left to the estimate.
            model_rate_dot_frd_radps2: v.rate_derivative(&est.rates_frd_radps, u, T::zero(), &none),
        });
    }

    /// The step's output: `raw` clamped into the box `bx` (see
    /// [`super::saturate`]), remembered as the input sent (the last call of
    /// a controller's step).
    pub(crate) fn finish(
        &mut self,
        bx: &InputBox<T>,
        v: &Vehicle<T>,
        est: &StateEstimate<T>,
        raw: &Input<T>,
    ) -> ControlOutput<T> {
        let out = super::saturate(bx, raw);
        self.record(v, est, &out.u);
        out
    }

    /// The next step does not follow this one by one period: skip one update
    /// (the differences would span the gap), keep the estimates.
    pub fn resume(&mut self) {
        self.pending = None;
    }

    /// Forgets everything (a new flight).
    pub fn reset(&mut self) {
        self.d_stage = Vector3::zeros();
        self.d_hat = Vector3::zeros();
        self.m_hat = Vector3::zeros();
        self.pending = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{euler_to_quat, VehicleParams};
    use nalgebra::Vector4;

    fn thrust(u1: f64) -> Input<f64> {
        Vector4::new(u1, 0.0, 0.0, 0.0)
    }

    /// A point mass with the model's translational dynamics plus `dist`
    /// (m/s², NED), thrust `u1` along the body's −z at attitude `att`,
    /// integrated exactly over `dt` for the velocity (constant acceleration
    /// within a step: the model's own assumption, so the test isolates the
    /// observer's arithmetic from integration error).
    fn step(p: &VehicleParams<f64>, est: &mut StateEstimate<f64>, u1: f64, dist: Vector3<f64>, dt: f64) {
        let r = quat_to_rotation(&est.att);
        let v = est.vel_ned_mps;
        let mut a = Vector3::new(
            -r[(0, 2)] * u1 / p.mass_kg,
            -r[(1, 2)] * u1 / p.mass_kg,
            -r[(2, 2)] * u1 / p.mass_kg + p.gravity_mps2,
        );
        for i in 0..3 {
            a[i] -= p.kt_nspm[i] / p.mass_kg * v[i];
        }
        a += dist;
        est.pos_ned_m += v * dt + a * (0.5 * dt * dt);
        est.vel_ned_mps += a * dt;
    }

    fn at_rest(att: Vector4<f64>) -> StateEstimate<f64> {
        StateEstimate {
            pos_ned_m: Vector3::zeros(),
            vel_ned_mps: Vector3::zeros(),
            att,
            rates_frd_radps: Vector3::zeros(),
        }
    }

    #[test]
    fn learns_a_constant_disturbance_at_its_time_constant() {
        // One stage of gain g = dt/τ: after k updates the error is (1 − g)^k
        // of the disturbance. Two stages of g = 2dt/τ: (1 − g)^k·(1 + k·g).
        // After 5τ: e⁻⁵ ≈ 0.7 % and 11·e⁻¹⁰ ≈ 0.05 %.
        let p = VehicleParams::<f64>::os4();
        let v = Vehicle::new(&p);
        let (dt, tau) = (0.002, 0.3);
        let mut one = AccelObserver::<f64>::new(tau, tau, dt, p.gravity_mps2).unwrap();
        let mut two = one.smoothed();
        let dist = Vector3::new(0.4, -0.3, 0.8);
        let mut est = at_rest(euler_to_quat(0.1, -0.05, 0.7));
        let steps = (5.0 * tau / dt) as usize;
        for k in 0..steps {
            one.observe(&est);
            two.observe(&est);
            let u1 = p.hover_thrust_n() * 0.9;
            one.record(&v, &est, &thrust(u1));
            two.record(&v, &est, &thrust(u1));
            step(&p, &mut est, u1, dist, dt);
            if k == steps / 5 {
                // After τ, exactly the recursions' values.
                let g = dt / tau;
                let want = 1.0 - (1.0 - g).powi(k as i32);
                let got = one.estimate()[0] / dist[0];
                assert!((got - want).abs() < 1e-9, "one stage: {got} vs {want}");
                let g = 2.0 * dt / tau;
                let want = 1.0 - (1.0 - g).powi(k as i32) * (1.0 + k as f64 * g);
                let got = two.estimate()[0] / dist[0];
                assert!((got - want).abs() < 1e-9, "two stages: {got} vs {want}");
            }
        }
        let err = (one.estimate() - dist).norm() / dist.norm();
        assert!(err < 0.008, "one stage: relative error {err}");
        let err = (two.estimate() - dist).norm() / dist.norm();
        assert!(err < 0.001, "two stages: relative error {err}");
    }

    #[test]
    fn the_second_stage_passes_less_velocity_noise() {
        // White velocity noise σ at rest, no disturbance. One stage passes
        // the differenced noise at g/dt = 1/τ: jitter ≈ σ/τ. The second stage
        // averages that white jitter over τ/2 steps: several times smaller.
        let p = VehicleParams::<f64>::os4();
        let v = Vehicle::new(&p);
        let (dt, tau, sigma) = (0.002, 0.05, 0.02);
        let mut one = AccelObserver::<f64>::new(tau, 1.0, dt, p.gravity_mps2).unwrap();
        let mut two = one.smoothed();
        let mut est = at_rest(euler_to_quat(0.0, 0.0, 0.0));
        let mut seed = 12345u64;
        let mut gauss = || {
            // Sum of 12 uniforms − 6: unit variance, near-Gaussian.
            (0..12)
                .map(|_| {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (seed >> 11) as f64 / (1u64 << 53) as f64
                })
                .sum::<f64>()
                - 6.0
        };
        let (mut s1, mut s2) = (0.0, 0.0);
        let n = 20000;
        for k in 0..n {
            est.vel_ned_mps[0] = sigma * gauss();
            one.observe(&est);
            two.observe(&est);
            one.record(&v, &est, &thrust(p.hover_thrust_n()));
            two.record(&v, &est, &thrust(p.hover_thrust_n()));
            if k > 1000 {
                s1 += one.estimate()[0].powi(2);
                s2 += two.estimate()[0].powi(2);
            }
        }
        let (r1, r2) = ((s1 / n as f64).sqrt(), (s2 / n as f64).sqrt());
        // One stage: ≈ σ/τ (0.4 m/s²); two: ≈ 5× less.
        assert!((0.25..0.6).contains(&r1), "one stage: {r1}");
        assert!(r2 < r1 / 3.0, "two stages {r2} vs one {r1}");
    }

    #[test]
    fn a_saturated_episode_does_not_wind_it_up() {
        // The thrust the controller *sent* is what the observer models, so a
        // long stretch at the box's limit (here: asking for more than the
        // rotors give, the vehicle falling short) leaves the estimate at the
        // true disturbance, where an integrator of the tracking error would
        // have kept growing.
        let p = VehicleParams::<f64>::os4();
        let dt = 0.002;
        let mut obs = AccelObserver::<f64>::new(0.3, 0.3, dt, p.gravity_mps2).unwrap();
        let dist = Vector3::new(0.0, 0.0, 1.2); // 12 % heavier, say
        let u_max = p.input_box().hi[0];
        let mut est = at_rest(euler_to_quat(0.0, 0.0, 0.0));
        for _ in 0..3000 {
            obs.observe(&est);
            obs.record(&Vehicle::new(&p), &est, &thrust(u_max)); // the controller wants more; the box says u_max
            step(&p, &mut est, u_max, dist, dt);
        }
        assert!((obs.estimate() - dist).norm() < 1e-6, "{}", obs.estimate());
    }

    #[test]
    fn is_bounded_and_ignores_a_gap() {
        let p = VehicleParams::<f64>::os4();
        let dt = 0.002;
        let mut obs = AccelObserver::<f64>::new(0.3, 0.3, dt, p.gravity_mps2).unwrap();
        let mut est = at_rest(euler_to_quat(0.0, 0.0, 0.0));
        let v = Vehicle::new(&p);
        let lim = DISTURBANCE_LIMIT_G * p.gravity_mps2;
        // A 100 m/s jump every step (50 000 m/s² "measured"): the estimate
        // approaches the limit and never passes it.
        for _ in 0..2000 {
            obs.record(&v, &est, &thrust(p.hover_thrust_n()));
            est.vel_ned_mps[0] += 100.0;
            obs.observe(&est);
            assert!(obs.estimate()[0] <= lim);
        }
        assert!(obs.estimate()[0] > 0.999 * lim, "{}", obs.estimate()[0]);
        // After a gap, no update spans it.
        let before = obs.estimate();
        obs.record(&v, &est, &thrust(p.hover_thrust_n()));
        obs.resume();
        est.vel_ned_mps[0] = -100.0;
        obs.observe(&est);
        assert_eq!(obs.estimate(), before);
        obs.reset();
        assert_eq!(obs.estimate(), Vector3::zeros());
    }

    #[test]
    fn learns_a_constant_moment_and_cancels_it() {
        // Rates integrated exactly under a constant torque input and a
        // constant disturbance moment (no gyroscopic coupling: rotation about
        // one axis at a time), with the rate damping of the model.
        let p = VehicleParams::<f64>::os4();
        let v = Vehicle::new(&p);
        let (dt, tau) = (0.002, 0.02);
        let mut obs = AccelObserver::<f64>::new(0.3, tau, dt, p.gravity_mps2).unwrap();
        let moment = [0.004, -0.003, 0.002]; // N·m, body FRD
        for axis in 0..3 {
            obs.reset();
            let mut est = at_rest(euler_to_quat(0.0, 0.0, 0.0));
            let mut u = thrust(p.hover_thrust_n());
            u[1 + axis] = 0.01;
            let (i, kr) = (p.inertia_kgm2[axis], p.kr_nms[axis]);
            let lever = if axis < 2 { p.arm_m } else { 1.0 };
            for _ in 0..200 {
                obs.observe(&est);
                obs.record(&v, &est, &u);
                // ω̇ = (lever·u + M − kr·ω)/I: exact step of the linear ODE.
                let w = est.rates_frd_radps[axis];
                let w_inf = (lever * u[1 + axis] + moment[axis]) / kr;
                est.rates_frd_radps[axis] = w_inf + (w - w_inf) * (-kr / i * dt).exp();
            }
            // The finite difference of an exponential is not its derivative at
            // the step's start: the estimate is right to O(dt·kr/I) ≈ 2.7 %.
            let want = moment[axis] / i;
            let got = obs.moment_estimate()[axis];
            assert!((got - want).abs() < 0.03 * want.abs(), "axis {axis}: {got} vs {want}");
            // The feed-forward is the torque input that cancels it.
            let ff = obs.torque_feedforward(&v)[axis];
            assert!(
                (lever * ff + moment[axis]).abs() < 0.03 * moment[axis].abs(),
                "axis {axis}: {ff}"
            );
        }
    }

    #[test]
    fn refuses_a_time_constant_below_its_period() {
        for (tau, dt) in [
            (0.001, 0.002),
            (f64::NAN, 0.002),
            (0.3, 0.0),
            (0.3, -1.0),
            (f64::INFINITY, 0.002),
        ] {
            assert_eq!(
                AccelObserver::<f32>::new(0.3, tau, dt, 9.81),
                Err(ControlError::InvalidParameter)
            );
            assert_eq!(
                AccelObserver::<f32>::new(tau, 0.3, dt, 9.81),
                Err(ControlError::InvalidParameter),
                "{tau} {dt}"
            );
        }
        assert!(!AccelObserver::<f32>::off().is_on());
    }
}
