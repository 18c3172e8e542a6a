//! The nonlinear plant in `f64`: the core's equations (docs/book/src/model.md §4–6), integrated
//! with fixed-step RK4 and sub-steps, rotor clamping and optional rotor lag,
//! external disturbances, quaternion renormalisation after every step.

use crate::disturbance::DisturbanceSet;
use fc_core::{
    clamp_speed, euler_state_to_quat, gyro_speed, quat_normalize, quat_state_to_euler, realised_inputs, rotor_speeds,
    AttitudeForm, Disturbance, EulerState, Input, QuatState, Vehicle, VehicleParams,
};
use nalgebra::{SVector, Vector3, Vector4};

/// How the plant is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlantConfig {
    /// Equations integrated.
    pub model: AttitudeForm,
    /// The true vehicle (may differ from the controller's model: `mismatch`).
    pub params: VehicleParams<f64>,
    /// RK4 rate, Hz: each `step(dt)` is cut into `ceil(dt·rate)` equal sub-steps.
    pub integration_hz: f64,
    /// First-order rotor lag (docs/book/src/model.md §6) on or off.
    pub rotor_lag: bool,
    /// Time-varying external force/moment.
    pub disturbance: DisturbanceSet,
    /// Steady wind, NED, m/s: drag acts on the velocity relative to the air,
    /// i.e. an added force `kt ⊙ wind` (the true vehicle's drag coefficients).
    pub wind_ned_mps: Vector3<f64>,
}

impl PlantConfig {
    /// Nominal OS4 plant at 1 kHz, no lag, no disturbance.
    pub fn nominal(model: AttitudeForm) -> Self {
        Self {
            model,
            params: VehicleParams::OS4,
            integration_hz: 1000.0,
            rotor_lag: false,
            disturbance: DisturbanceSet::NONE,
            wind_ned_mps: Vector3::zeros(),
        }
    }

    /// Applies a disturbance set: `mismatch` changes the true parameters and
    /// turns the rotor lag on (docs/book/src/model.md §9); `wind` adds the force/moment profile.
    pub fn with_disturbance(mut self, d: DisturbanceSet) -> Self {
        if d.mismatch {
            self.params = DisturbanceSet::mismatched(&self.params);
            self.rotor_lag = true;
        }
        self.disturbance = d;
        self
    }
}

/// The body state in whichever form the plant integrates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BodyState {
    /// Euler-form state.
    Euler(EulerState<f64>),
    /// Quaternion-form state.
    Quat(QuatState<f64>),
}

/// The simulated vehicle.
#[derive(Debug, Clone)]
pub struct Plant {
    cfg: PlantConfig,
    vehicle: Vehicle<f64>,
    body: BodyState,
    /// Actual rotor speeds, rad/s.
    omega: Vector4<f64>,
    t: f64,
    /// Resting on the ground ([`Plant::contact_ground`]).
    grounded: bool,
}

/// `self + a·other`, the only operation RK4 needs.
trait Axpy: Copy {
    fn axpy(&self, a: f64, other: &Self) -> Self;
}

impl<const N: usize> Axpy for SVector<f64, N> {
    #[inline(always)]
    fn axpy(&self, a: f64, o: &Self) -> Self {
        // A plain loop over the storage: nalgebra's `self + o * a` builds a
        // temporary and costs a third more time here.
        let mut out = *self;
        for (x, y) in out.as_mut_slice().iter_mut().zip(o.as_slice()) {
            *x += a * y;
        }
        out
    }
}

impl<const N: usize> Axpy for (SVector<f64, N>, Vector4<f64>) {
    #[inline(always)]
    fn axpy(&self, a: f64, o: &Self) -> Self {
        (self.0 + o.0 * a, self.1 + o.1 * a)
    }
}

/// One classical RK4 step of `ẋ = f(t, x)` from `t` over `h`, accumulating the
/// weighted stages as it goes so only one stage derivative is live at a time.
#[inline(always)]
fn rk4<S: Axpy>(f: impl Fn(f64, &S) -> S, x: &S, t: f64, h: f64) -> S {
    let k = f(t, x);
    let mut acc = x.axpy(h / 6.0, &k);
    let k = f(t + 0.5 * h, &x.axpy(0.5 * h, &k));
    acc = acc.axpy(h / 3.0, &k);
    let k = f(t + 0.5 * h, &x.axpy(0.5 * h, &k));
    acc = acc.axpy(h / 3.0, &k);
    let k = f(t + h, &x.axpy(h, &k));
    acc.axpy(h / 6.0, &k)
}

/// Derivative of the body state in either form.
trait Body: Axpy {
    fn deriv(v: &Vehicle<f64>, x: &Self, u: &Input<f64>, wr: f64, d: &Disturbance<f64>) -> Self;
    fn renormalise(&mut self);
}

impl Body for EulerState<f64> {
    #[inline(always)]
    fn deriv(v: &Vehicle<f64>, x: &Self, u: &Input<f64>, wr: f64, d: &Disturbance<f64>) -> Self {
        v.euler_derivative(x, u, wr, d)
    }
    fn renormalise(&mut self) {}
}

impl Body for QuatState<f64> {
    #[inline(always)]
    fn deriv(v: &Vehicle<f64>, x: &Self, u: &Input<f64>, wr: f64, d: &Disturbance<f64>) -> Self {
        v.quat_derivative(x, u, wr, d)
    }
    fn renormalise(&mut self) {
        let q = self.fixed_rows::<4>(6).into_owned();
        let n2 = q.norm_squared();
        // After one RK4 step |q|² − 1 is ~1e-13: one Newton step of 1/sqrt(n2)
        // about 1, (3 − n2)/2, leaves an error of ~(n2 − 1)², i.e. rounding.
        // Far from unit length (never seen in flight) fall back to the exact form.
        let q = if (n2 - 1.0).abs() < 1e-6 {
            q * (1.5 - 0.5 * n2)
        } else {
            quat_normalize(&q)
        };
        self.fixed_rows_mut::<4>(6).copy_from(&q);
    }
}

impl Plant {
    /// A plant at `initial` (quaternion form; converted for the Euler plant)
    /// with rotors spinning at the hover speed.
    pub fn new(cfg: PlantConfig, initial: &QuatState<f64>) -> Self {
        let body = match cfg.model {
            AttitudeForm::Euler => BodyState::Euler(quat_state_to_euler(initial)),
            AttitudeForm::Quaternion => BodyState::Quat(*initial),
        };
        let w = cfg.params.hover_rotor_speed_radps();
        Self {
            vehicle: Vehicle::new(&cfg.params),
            cfg,
            body,
            omega: Vector4::repeat(w),
            t: 0.0,
            grounded: false,
        }
    }

    /// Ground contact with a flat, rigid ground at `ground_down_m` (NED
    /// down): a body that has sunk below it is put back on it at rest,
    /// level at its heading (the ground takes the rest of the step's
    /// motion). While it rests, the ground carries what the thrust does
    /// not, so the accelerometer reads the support
    /// ([`Plant::specific_force_frd`]); a thrust above the weight lifts it
    /// off at the next step. Call after each [`Plant::step`].
    pub fn contact_ground(&mut self, ground_down_m: f64) {
        let x = self.quat_state();
        if x[2] <= ground_down_m {
            self.grounded = x[2] >= ground_down_m - 1e-9 && self.grounded;
            return;
        }
        let yaw = fc_core::quat_to_euler(&x.fixed_rows::<4>(6).into_owned())[2];
        let rest = fc_core::hover_quat_state(&Vector3::new(x[0], x[1], ground_down_m), yaw);
        self.body = match self.body {
            BodyState::Euler(_) => BodyState::Euler(quat_state_to_euler(&rest)),
            BodyState::Quat(_) => BodyState::Quat(rest),
        };
        self.grounded = true;
    }

    /// Resting on the ground (after [`Plant::contact_ground`]).
    pub fn grounded(&self) -> bool {
        self.grounded
    }

    /// Sets the rotor speeds (rad/s, clamped to `[0, Ωmax]`).
    pub fn set_rotor_speeds(&mut self, omega: Vector4<f64>) {
        self.omega = omega.map(|w| clamp_speed(&self.cfg.params, w));
    }

    /// Simulated time, s.
    pub fn time(&self) -> f64 {
        self.t
    }

    /// The configuration.
    pub fn config(&self) -> &PlantConfig {
        &self.cfg
    }

    /// Body state in the plant's own form.
    pub fn body(&self) -> &BodyState {
        &self.body
    }

    /// State as a quaternion-form vector (converted from Euler if needed).
    pub fn quat_state(&self) -> QuatState<f64> {
        match &self.body {
            BodyState::Euler(x) => euler_state_to_quat(x),
            BodyState::Quat(x) => *x,
        }
    }

    /// State as an Euler-form vector (converted from the quaternion if needed).
    pub fn euler_state(&self) -> EulerState<f64> {
        match &self.body {
            BodyState::Euler(x) => *x,
            BodyState::Quat(x) => quat_state_to_euler(x),
        }
    }

    /// NED position, m.
    pub fn position(&self) -> Vector3<f64> {
        match &self.body {
            BodyState::Euler(x) => x.fixed_rows::<3>(0).into_owned(),
            BodyState::Quat(x) => x.fixed_rows::<3>(0).into_owned(),
        }
    }

    /// Actual rotor speeds, rad/s.
    pub fn rotor_speeds(&self) -> Vector4<f64> {
        self.omega
    }

    /// What an ideal accelerometer measures now: the specific force
    /// (acceleration less gravity) in body FRD, m/s², from the same forces
    /// the integrator uses (thrust, drag, wind, disturbance).
    pub fn specific_force_frd(&self) -> Vector3<f64> {
        let x = self.quat_state();
        let p = &self.cfg.params;
        let mut d = self.cfg.disturbance.at(self.t);
        d.force_ned_n += Vector3::from(p.kt_nspm).component_mul(&self.cfg.wind_ned_mps);
        let dx = self
            .vehicle
            .quat_derivative(&x, &self.realised_inputs(), gyro_speed(&self.omega), &d);
        let mut acc = Vector3::new(dx[3], dx[4], dx[5]);
        if self.grounded && acc[2] >= 0.0 {
            // The ground supports it: no acceleration.
            acc = Vector3::zeros();
        }
        let r = fc_core::quat_to_rotation(&x.fixed_rows::<4>(6).into_owned());
        r.transpose() * (acc - Vector3::new(0.0, 0.0, p.gravity_mps2))
    }

    /// Inputs the rotors realise right now (after clamping and lag).
    pub fn realised_inputs(&self) -> Input<f64> {
        realised_inputs(&self.cfg.params, &self.omega)
    }

    /// Inputs the rotors would realise at once for command `u_cmd`: the
    /// clamped mixer output without lag, the current rotor output with lag.
    pub fn inputs_realised_for(&self, u_cmd: &Input<f64>) -> Input<f64> {
        if self.cfg.rotor_lag {
            self.realised_inputs()
        } else {
            realised_inputs(&self.cfg.params, &rotor_speeds(&self.cfg.params, u_cmd))
        }
    }

    /// Advances `dt` seconds with the command `u_cmd` held (zero-order hold).
    /// The command goes through the mixer inverse and rotor clamping; with
    /// lag on, rotors approach `k·Ω_cmd` with time constant τ.
    pub fn step(&mut self, u_cmd: &Input<f64>, dt: f64) {
        if dt.is_nan() || dt <= 0.0 {
            return;
        }
        // Sub-steps: ceil(dt·rate) without libm's ceil (not inlined on baseline x86-64).
        let f = dt * self.cfg.integration_hz - 1e-9;
        let n = (f as usize + usize::from(f.fract() > 0.0)).max(1);
        let h = dt / n as f64;
        let omega_cmd = rotor_speeds(&self.cfg.params, u_cmd);
        match &mut self.body {
            BodyState::Euler(x) => Self::integrate(
                &self.cfg,
                &self.vehicle,
                x,
                &mut self.omega,
                &omega_cmd,
                &mut self.t,
                (h, n),
            ),
            BodyState::Quat(x) => Self::integrate(
                &self.cfg,
                &self.vehicle,
                x,
                &mut self.omega,
                &omega_cmd,
                &mut self.t,
                (h, n),
            ),
        }
    }

    fn integrate<B: Body>(
        cfg: &PlantConfig,
        v: &Vehicle<f64>,
        x: &mut B,
        omega: &mut Vector4<f64>,
        omega_cmd: &Vector4<f64>,
        t: &mut f64,
        (h, n): (f64, usize),
    ) where
        (B, Vector4<f64>): Axpy,
    {
        let p = &cfg.params;
        let wind_force = Vector3::from(p.kt_nspm).component_mul(&cfg.wind_ned_mps);
        let dist = |tt: f64| {
            let mut d = cfg.disturbance.at(tt);
            d.force_ned_n += wind_force;
            d
        };
        let t0 = *t;
        for i in 0..n {
            let ti = t0 + i as f64 * h;
            if cfg.rotor_lag {
                // The first-order lag in closed form over the sub-step,
                // ω(s) = ω∞ + (ω₀ − ω∞)·e^{−s/τ} with ω∞ = k·Ω_cmd, fed to RK4
                // at its stage times: exact and stable for every τ > 0 (an RK4
                // of the lag itself is unstable for τ below ≈ h/2.8).
                let (k, tau) = (p.rotor_gain, p.rotor_tau_s);
                let w_inf = omega_cmd * k;
                let w0 = *omega;
                let at = |s: f64| w_inf + (w0 - w_inf) * (-s / tau).exp();
                let stages = [w0, at(0.5 * h), at(h)];
                let f = |tt: f64, s: &B| {
                    // RK4 evaluates at ti, ti + h/2 (twice) and ti + h.
                    let w = &stages[usize::from(tt > ti) + usize::from(tt > ti + 0.75 * h)];
                    B::deriv(v, s, &realised_inputs(p, w), gyro_speed(w), &dist(tt))
                };
                *x = rk4(f, x, ti, h);
                *omega = stages[2].map(|w| clamp_speed(p, w));
            } else {
                *omega = *omega_cmd;
                let u = realised_inputs(p, omega);
                let wr = gyro_speed(omega);
                let f = |tt: f64, s: &B| B::deriv(v, s, &u, wr, &dist(tt));
                *x = rk4(f, x, ti, h);
            }
            x.renormalise();
        }
        *t = t0 + n as f64 * h;
    }
}
