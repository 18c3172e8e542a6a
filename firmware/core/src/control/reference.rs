//! From a desired acceleration to the attitude and thrust that produce it
//! (thesis 3.79, 3.85, 3.86 — an exact inversion of the translational
//! dynamics of docs/book/src/model.md §4), and the reference feed-forward modes.

use super::Setpoint;
use crate::lit;
use crate::math as trig;
use crate::math::limit;
use crate::model::VehicleParams;
use nalgebra::{RealField, Vector3};

/// How much of the reference the controllers feed forward.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "lowercase")
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReferenceMode {
    /// As the thesis: the reference position and velocity enter the feedback
    /// (3.78, 3.83, 3.84); no acceleration, attitude or thrust feed-forward.
    Thesis,
    /// Adds the reference acceleration: the attitude and thrust it implies are
    /// fed forward, so moving references are tracked without feedback lag.
    Feedforward,
}

impl ReferenceMode {
    /// Both modes, feed-forward first.
    pub const ALL: [ReferenceMode; 2] = [ReferenceMode::Feedforward, ReferenceMode::Thesis];

    /// Lower-case name (`feedforward`, `thesis`): command line and JSON.
    pub const fn name(self) -> &'static str {
        match self {
            ReferenceMode::Thesis => "thesis",
            ReferenceMode::Feedforward => "feedforward",
        }
    }
}

/// Desired roll, pitch and thrust for a desired acceleration and heading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiltThrust<T: RealField + Copy> {
    /// Desired roll φd, rad.
    pub roll_rad: T,
    /// Desired pitch θd, rad.
    pub pitch_rad: T,
    /// Thrust that gives the desired vertical acceleration at this tilt, N.
    pub thrust_n: T,
}

/// Largest commanded tilt, rad (45°): keeps the thrust axis well away from
/// horizontal, where altitude cannot be held.
pub const MAX_TILT_RAD: f64 = core::f64::consts::FRAC_PI_4;

/// Attitude and thrust for acceleration `acc_d` (NED, m/s²) at velocity `vel`
/// (for drag compensation) and heading `yaw` (thesis 3.85, 3.86, 3.79 with the
/// desired angles). With `A = acc_d + kt∘vel/m`:
/// `θd = atan((−cψ·Ax − sψ·Ay)/(g − Az))`,
/// `φd = atan((−sψ·Ax + cψ·Ay)·cos θd/(g − Az))`,
/// `U1 = m(g − Az)/(cos φd cos θd)`.
/// `g − Az` is kept ≥ 0.2 g (no commanded free fall) and the tilt ≤ 45°.
pub fn tilt_and_thrust<T: RealField + Copy>(
    p: &VehicleParams<T>,
    acc_d: &Vector3<T>,
    vel: &Vector3<T>,
    yaw: T,
) -> TiltThrust<T> {
    Tilt::new(p, acc_d, vel, yaw).tt
}

/// `sin` and `cos` of `angle`, which is `atan(t)` when `free`, else the
/// tilt limit's `±MAX_TILT_RAD` (or what [`limit`] made of a NaN).
/// Algebraic where it can be, which costs a square root and a division in
/// place of a sine and a cosine (the MPC takes 20 of these a step):
/// `sin atan t = t/√(1+t²)`, `cos atan t = 1/√(1+t²)` (`|t| ≤ 1` when
/// free, so `t²` cannot overflow), and at the limit `sin, cos = ±1/√2, 1/√2`
/// for the 45° of [`MAX_TILT_RAD`].
fn sin_cos_of_atan<T: RealField + Copy>(t: T, free: bool, angle: T) -> (T, T) {
    if free {
        let r = T::one() / trig::sqrt(T::one() + t * t);
        return (t * r, r);
    }
    let lim = lit::<T>(MAX_TILT_RAD);
    let h = lit::<T>(MAX_TILT_SIN_COS);
    if angle == lim {
        (h, h)
    } else if angle == -lim {
        (-h, h)
    } else {
        trig::sin_cos(angle)
    }
}

/// `sin` and `cos` of [`MAX_TILT_RAD`] (equal at 45°).
const MAX_TILT_SIN_COS: f64 = core::f64::consts::FRAC_1_SQRT_2;

/// [`tilt_and_thrust`] with the intermediate values its time derivative
/// reuses ([`AttitudeRef::feedforward`]).
struct Tilt<T: RealField + Copy> {
    tt: TiltThrust<T>,
    /// The drag-compensated acceleration `A` (x and y), m/s².
    ax: T,
    ay: T,
    /// `g − Az`, m/s², and whether its 0.2 g floor is inactive.
    lift: T,
    lift_free: bool,
    /// sin and cos of the heading.
    s_yaw: T,
    c_yaw: T,
    /// Whether the pitch and roll are inside their ±45° limit.
    pitch_free: bool,
    roll_free: bool,
    /// sin and cos of the roll and pitch.
    s_roll: T,
    c_roll: T,
    s_pitch: T,
    c_pitch: T,
}

impl<T: RealField + Copy> Tilt<T> {
    fn new(p: &VehicleParams<T>, acc_d: &Vector3<T>, vel: &Vector3<T>, yaw: T) -> Self {
        let m = p.mass_kg;
        let g = p.gravity_mps2;
        let ax = acc_d[0] + p.kt_nspm[0] / m * vel[0];
        let ay = acc_d[1] + p.kt_nspm[1] / m * vel[1];
        let az = acc_d[2] + p.kt_nspm[2] / m * vel[2];
        let floor = lit::<T>(0.2) * g;
        let lift = if g - az > floor { g - az } else { floor };
        let (s, c) = trig::sin_cos(yaw);
        let max_tilt = lit::<T>(MAX_TILT_RAD);
        let u = (-c * ax - s * ay) / lift;
        let pitch_free = u.atan();
        let pitch = limit(pitch_free, max_tilt);
        let (s_pitch, c_pitch) = sin_cos_of_atan(u, pitch == pitch_free, pitch);
        let v = (-s * ax + c * ay) * c_pitch / lift;
        let roll_free = v.atan();
        let roll = limit(roll_free, max_tilt);
        let (s_roll, c_roll) = sin_cos_of_atan(v, roll == roll_free, roll);
        Self {
            tt: TiltThrust {
                roll_rad: roll,
                pitch_rad: pitch,
                thrust_n: m * lift / (c_roll * c_pitch),
            },
            ax,
            ay,
            lift,
            lift_free: g - az > floor,
            s_yaw: s,
            c_yaw: c,
            pitch_free: pitch == pitch_free,
            roll_free: roll == roll_free,
            s_roll,
            c_roll,
            s_pitch,
            c_pitch,
        }
    }

    /// `(φ̇, θ̇)`, rad/s: the time derivative of the roll and pitch when the
    /// drag-compensated acceleration changes at `a_dot` (m/s³) and the
    /// heading at `yaw_rate` (rad/s). Differentiates the formulas of
    /// [`tilt_and_thrust`] (a limit that is active holds its angle: rate 0).
    fn rates(&self, a_dot: &Vector3<T>, yaw_rate: T) -> (T, T) {
        let (s, c, ax, ay, lift) = (self.s_yaw, self.c_yaw, self.ax, self.ay, self.lift);
        let lift_dot = if self.lift_free { -a_dot[2] } else { T::zero() };
        let one = T::one();
        // θ = atan(u), u = (−cψ·Ax − sψ·Ay)/L.
        let num_p = -c * ax - s * ay;
        let num_p_dot = -c * a_dot[0] - s * a_dot[1] + yaw_rate * (s * ax - c * ay);
        let u = num_p / lift;
        let theta_dot = if self.pitch_free {
            (num_p_dot - u * lift_dot) / lift / (one + u * u)
        } else {
            T::zero()
        };
        // φ = atan(v), v = (−sψ·Ax + cψ·Ay)·cos θ / L.
        let num_r = -s * ax + c * ay;
        let num_r_dot = -s * a_dot[0] + c * a_dot[1] + yaw_rate * num_p;
        let v = num_r * self.c_pitch / lift;
        let phi_dot = if self.roll_free {
            (num_r_dot * self.c_pitch - num_r * self.s_pitch * theta_dot - v * lift_dot) / lift / (one + v * v)
        } else {
            T::zero()
        };
        (phi_dot, theta_dot)
    }
}

/// The attitude, thrust and body rates a reference implies.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeRef<T: RealField + Copy> {
    /// Roll φ, rad.
    pub roll_rad: T,
    /// Pitch θ, rad.
    pub pitch_rad: T,
    /// Heading ψ, rad.
    pub yaw_rad: T,
    /// Thrust, N.
    pub thrust_n: T,
    /// Body rates (p, q, r) of the reference attitude, FRD, rad/s.
    pub rates_frd_radps: Vector3<T>,
}

impl<T: RealField + Copy> AttitudeRef<T> {
    /// Level at the setpoint's heading, hover thrust, no rates (what the
    /// thesis' LQR regulates to).
    pub fn level(p: &VehicleParams<T>, sp: &Setpoint<T>) -> Self {
        Self {
            roll_rad: T::zero(),
            pitch_rad: T::zero(),
            yaw_rad: sp.yaw_rad,
            thrust_n: p.hover_thrust_n(),
            rates_frd_radps: Vector3::zeros(),
        }
    }

    /// What the reference's acceleration implies ([`tilt_and_thrust`] at the
    /// reference velocity and heading), with body rates from the exact time
    /// derivative of that map along the reference's jerk and yaw rate.
    pub fn feedforward(p: &VehicleParams<T>, sp: &Setpoint<T>) -> Self {
        Self::feedforward_trig(p, sp).0
    }

    /// [`Self::for_mode`] with the sine and cosine of its roll and pitch,
    /// `[sin φ, cos φ, sin θ, cos θ]` (computed on the way: a caller that
    /// needs them does not take them again).
    pub(crate) fn for_mode_trig(p: &VehicleParams<T>, sp: &Setpoint<T>, mode: ReferenceMode) -> (Self, [T; 4]) {
        match mode {
            ReferenceMode::Thesis => (Self::level(p, sp), [T::zero(), T::one(), T::zero(), T::one()]),
            ReferenceMode::Feedforward => Self::feedforward_trig(p, sp),
        }
    }

    /// [`Self::feedforward`] and `[sin φ, cos φ, sin θ, cos θ]`.
    fn feedforward_trig(p: &VehicleParams<T>, sp: &Setpoint<T>) -> (Self, [T; 4]) {
        let t = Tilt::new(p, &sp.acc_ned_mps2, &sp.vel_ned_mps, sp.yaw_rad);
        // d/dt of the drag-compensated acceleration along the reference.
        let m = p.mass_kg;
        let a_dot = Vector3::new(
            sp.jerk_ned_mps3[0] + p.kt_nspm[0] / m * sp.acc_ned_mps2[0],
            sp.jerk_ned_mps3[1] + p.kt_nspm[1] / m * sp.acc_ned_mps2[1],
            sp.jerk_ned_mps3[2] + p.kt_nspm[2] / m * sp.acc_ned_mps2[2],
        );
        let (phi_dot, theta_dot) = t.rates(&a_dot, sp.yaw_rate_radps);
        let psi_dot = sp.yaw_rate_radps;
        // Euler rates → body rates (ZYX).
        let (sphi, cphi, sth, cth) = (t.s_roll, t.c_roll, t.s_pitch, t.c_pitch);
        let rates = Vector3::new(
            phi_dot - psi_dot * sth,
            theta_dot * cphi + psi_dot * sphi * cth,
            -theta_dot * sphi + psi_dot * cphi * cth,
        );
        let ar = Self {
            roll_rad: t.tt.roll_rad,
            pitch_rad: t.tt.pitch_rad,
            yaw_rad: sp.yaw_rad,
            thrust_n: t.tt.thrust_n,
            rates_frd_radps: rates,
        };
        (ar, [sphi, cphi, sth, cth])
    }

    /// [`Self::level`] or [`Self::feedforward`] by mode.
    pub fn for_mode(p: &VehicleParams<T>, sp: &Setpoint<T>, mode: ReferenceMode) -> Self {
        match mode {
            ReferenceMode::Thesis => Self::level(p, sp),
            ReferenceMode::Feedforward => Self::feedforward(p, sp),
        }
    }

    /// The attitude and thrust to aim at when an estimated disturbance
    /// `d_hat` (NED, m/s², see [`super::observer::AccelObserver`]) adds to
    /// the vehicle's acceleration: those that produce the reference's
    /// acceleration minus `d_hat` (the target calculation of offset-free
    /// control). In `Thesis` mode the reference's derivatives stay out (only
    /// `−d_hat` is fed forward, no rates); with `d_hat = 0` this is
    /// [`Self::for_mode`].
    pub fn with_disturbance(p: &VehicleParams<T>, sp: &Setpoint<T>, mode: ReferenceMode, d_hat: &Vector3<T>) -> Self {
        if d_hat.iter().all(|v| *v == T::zero()) {
            return Self::for_mode(p, sp, mode);
        }
        let target = match mode {
            ReferenceMode::Feedforward => Setpoint {
                acc_ned_mps2: sp.acc_ned_mps2 - d_hat,
                ..*sp
            },
            ReferenceMode::Thesis => Setpoint {
                acc_ned_mps2: -d_hat,
                yaw_rate_radps: T::zero(),
                ..Setpoint::hold(sp.pos_ned_m, sp.yaw_rad)
            },
        };
        Self::feedforward(p, &target)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{euler_derivative, hover_euler_state, Disturbance, VehicleParams};
    use nalgebra::Vector4;

    #[test]
    fn tilt_and_thrust_produce_the_desired_acceleration() {
        // Independent truth: put the vehicle at the returned attitude with the
        // returned thrust and evaluate the nonlinear dynamics.
        let p = VehicleParams::<f64>::os4();
        for (acc, vel, yaw) in [
            (Vector3::new(1.0, -0.5, -0.8), Vector3::new(0.3, 0.2, -0.1), 0.3),
            (Vector3::new(-2.0, 1.5, 0.5), Vector3::new(-1.0, 0.0, 0.4), -2.4),
            (Vector3::zeros(), Vector3::zeros(), 1.0),
        ] {
            let tt = tilt_and_thrust(&p, &acc, &vel, yaw);
            let mut x = hover_euler_state(&Vector3::zeros(), yaw);
            x[3] = vel[0];
            x[4] = vel[1];
            x[5] = vel[2];
            x[6] = tt.roll_rad;
            x[7] = tt.pitch_rad;
            let u = Vector4::new(tt.thrust_n, 0.0, 0.0, 0.0);
            let d = euler_derivative(&p, &x, &u, 0.0, &Disturbance::none());
            let got = Vector3::new(d[3], d[4], d[5]);
            assert!((got - acc).norm() < 1e-12, "{got} vs {acc}");
        }
    }

    #[test]
    fn feedforward_rates_match_the_attitude_derivative() {
        // A circle's reference: the body rates of the implied attitude must equal
        // the finite-difference derivative of that attitude along the reference.
        let p = VehicleParams::<f64>::os4();
        let (r, w) = (2.0, 2.0 * core::f64::consts::PI / 6.0);
        let sp_at = |t: f64| {
            let (s, c) = trig::sin_cos(w * t);
            let (s2, c2) = trig::sin_cos(2.0 * w * t);
            Setpoint {
                // With a vertical oscillation too: the lift changes.
                pos_ned_m: Vector3::new(r * s, r * (1.0 - c), -1.0 + 0.5 * s2),
                vel_ned_mps: Vector3::new(r * w * c, r * w * s, w * c2),
                acc_ned_mps2: Vector3::new(-r * w * w * s, r * w * w * c, -2.0 * w * w * s2),
                jerk_ned_mps3: Vector3::new(-r * w * w * w * c, -r * w * w * w * s, -4.0 * w * w * w * c2),
                yaw_rad: 0.3 + 0.2 * t,
                yaw_rate_radps: 0.2,
            }
        };
        let t = 1.3;
        let a = AttitudeRef::feedforward(&p, &sp_at(t));
        let h = 1e-5;
        let (ap, am) = (
            AttitudeRef::feedforward(&p, &sp_at(t + h)),
            AttitudeRef::feedforward(&p, &sp_at(t - h)),
        );
        let q = |x: &AttitudeRef<f64>| crate::model::euler_to_quat(x.roll_rad, x.pitch_rad, x.yaw_rad);
        // ω = 2 q* ⊗ q̇ (body rates of a body→earth quaternion).
        let qd = (q(&ap) - q(&am)) / (2.0 * h);
        let w_fd = crate::model::quat_mul(&crate::model::quat_conj(&q(&a)), &qd) * 2.0;
        let want = Vector3::new(w_fd[1], w_fd[2], w_fd[3]);
        assert!(
            (a.rates_frd_radps - want).norm() < 1e-7,
            "{} vs {want}",
            a.rates_frd_radps
        );
        assert!(a.rates_frd_radps.norm() > 0.1);
    }

    #[test]
    fn sines_of_the_tilt_are_those_of_its_angles() {
        // The algebraic sine and cosine of atan(t), free and at the limit,
        // against f64's of the angle itself.
        let lim = MAX_TILT_RAD;
        assert!((MAX_TILT_SIN_COS - lim.sin()).abs() < 1e-15 && (MAX_TILT_SIN_COS - lim.cos()).abs() < 1e-15);
        let mut worst = 0.0f64;
        for i in 0..=4_000 {
            let t = -3.0f32 + 6.0 * i as f32 / 4_000.0;
            let free = t.atan();
            let angle = limit(free, lim as f32);
            let (s, c) = sin_cos_of_atan(t, angle == free, angle);
            let a = (t as f64).atan().clamp(-lim, lim);
            worst = worst.max((s as f64 - a.sin()).abs()).max((c as f64 - a.cos()).abs());
        }
        assert!(worst <= 2e-7, "{worst:e}");
        // A NaN request keeps what `limit` made of it (−45°).
        let (s, c) = sin_cos_of_atan(f32::NAN, false, limit(f32::NAN, lim as f32));
        assert!((s + MAX_TILT_SIN_COS as f32).abs() < 1e-7 && (c - MAX_TILT_SIN_COS as f32).abs() < 1e-7);
    }

    #[test]
    fn limits_hold_for_extreme_requests() {
        let p = VehicleParams::<f64>::os4();
        let tt = tilt_and_thrust(&p, &Vector3::new(100.0, -100.0, 50.0), &Vector3::zeros(), 0.0);
        assert!(tt.roll_rad.abs() <= MAX_TILT_RAD + 1e-12 && tt.pitch_rad.abs() <= MAX_TILT_RAD + 1e-12);
        assert!(tt.thrust_n > 0.0 && tt.thrust_n.is_finite());
    }
}
