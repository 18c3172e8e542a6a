//! The high-level commander's planner: one polynomial segment of degree 7
//! per axis (north, east, down, heading), from the reference's present
//! position, velocity and acceleration (jerk 0) to a goal at rest (velocity,
//! acceleration and jerk 0) in a given time, as the Crazyflie's `go_to`,
//! `takeoff` and `land` plan them. Eight conditions fix the eight
//! coefficients: the segment is unique.

use fc_core::control::Setpoint;
use nalgebra::Vector3;

/// Longest segment, s (the firmware's commands carry f32 seconds; a
/// longer one is refused).
pub const MAX_DURATION_S: f32 = 1000.0;
/// Farthest goal from the origin, m.
pub const MAX_DISTANCE_M: f32 = 1000.0;

/// Why a segment was not planned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlanError {
    /// Duration not finite, or not in (0, [`MAX_DURATION_S`]] s.
    Duration,
    /// A goal or start not finite, or farther than [`MAX_DISTANCE_M`].
    Position,
}

impl core::fmt::Display for PlanError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            // Whole numbers, written as integers: a float's `Display` would
            // link core's float formatting (≈ 17 KiB) into the images.
            PlanError::Duration => write!(f, "duration must be in (0, {}] s", MAX_DURATION_S as u32),
            PlanError::Position => write!(f, "positions must be finite and within {} m", MAX_DISTANCE_M as u32),
        }
    }
}

/// The reference at one instant: what the controllers fly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Reference {
    /// Position, NED, m.
    pub pos_ned_m: Vector3<f32>,
    /// Velocity, NED, m/s.
    pub vel_ned_mps: Vector3<f32>,
    /// Acceleration, NED, m/s².
    pub acc_ned_mps2: Vector3<f32>,
    /// Heading, rad.
    pub yaw_rad: f32,
    /// Heading rate, rad/s.
    pub yaw_rate_radps: f32,
}

impl From<&Setpoint<f32>> for Reference {
    /// A set-point as a reference (its jerk dropped: segments start at jerk 0).
    fn from(sp: &Setpoint<f32>) -> Self {
        Self {
            pos_ned_m: sp.pos_ned_m,
            vel_ned_mps: sp.vel_ned_mps,
            acc_ned_mps2: sp.acc_ned_mps2,
            yaw_rad: sp.yaw_rad,
            yaw_rate_radps: sp.yaw_rate_radps,
        }
    }
}

impl Reference {
    /// The set-point the controllers fly for it (jerk 0).
    pub fn setpoint(&self) -> Setpoint<f32> {
        let mut sp = Setpoint::hold(self.pos_ned_m, self.yaw_rad);
        sp.vel_ned_mps = self.vel_ned_mps;
        sp.acc_ned_mps2 = self.acc_ned_mps2;
        sp.yaw_rate_radps = self.yaw_rate_radps;
        sp
    }

    /// At rest at `pos` with heading `yaw`.
    pub fn at_rest(pos_ned_m: Vector3<f32>, yaw_rad: f32) -> Self {
        Self {
            pos_ned_m,
            vel_ned_mps: Vector3::zeros(),
            acc_ned_mps2: Vector3::zeros(),
            yaw_rad,
            yaw_rate_radps: 0.0,
        }
    }
}

/// The inverse of the end conditions' matrix (value, and first to third
/// derivatives in normalised time, of s⁴…s⁷ at s = 1).
const END_INV: [[f32; 4]; 4] = [
    [35.0, -15.0, 2.5, -1.0 / 6.0],
    [-84.0, 39.0, -7.0, 0.5],
    [70.0, -34.0, 6.5, -0.5],
    [-20.0, 10.0, -2.0, 1.0 / 6.0],
];

/// One axis' coefficients in normalised time s = t / T.
fn axis(p0: f32, v0: f32, a0: f32, p1: f32, t: f32) -> [f32; 8] {
    let c0 = p0;
    let c1 = v0 * t;
    let c2 = 0.5 * a0 * t * t;
    // Residuals at s = 1 of the value and its first three derivatives.
    let r = [p1 - (c0 + c1 + c2), -(c1 + 2.0 * c2), -(2.0 * c2), 0.0];
    let mut c = [c0, c1, c2, 0.0, 0.0, 0.0, 0.0, 0.0];
    for (k, row) in END_INV.iter().enumerate() {
        c[4 + k] = row.iter().zip(&r).map(|(m, r)| m * r).sum();
    }
    c
}

/// Value and first three derivatives of the degree-7 polynomial `c`
/// (coefficients from the constant up) at `t`, in one Horner pass: the
/// segments' (in their normalised time) and the uploaded trajectories'
/// ([`crate::trajectory`], in seconds).
pub(crate) fn eval_poly(c: &[f32; 8], t: f32) -> [f32; 4] {
    let (mut p, mut d1, mut d2, mut d3) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for &ck in c.iter().rev() {
        d3 = d3 * t + 3.0 * d2;
        d2 = d2 * t + 2.0 * d1;
        d1 = d1 * t + p;
        p = p * t + ck;
    }
    [p, d1, d2, d3]
}

/// `a − b` wrapped into (−π, π].
pub(crate) fn wrap(a: f32) -> f32 {
    let two_pi = 2.0 * core::f32::consts::PI;
    let w = a - two_pi * libm::floorf((a + core::f32::consts::PI) / two_pi);
    if w <= -core::f32::consts::PI {
        w + two_pi
    } else {
        w
    }
}

/// Refuses a segment whose duration, ends or headings are absurd.
fn check(from: &Reference, to_ned_m: &Vector3<f32>, to_yaw_rad: f32, duration_s: f32) -> Result<(), PlanError> {
    if !(duration_s.is_finite() && duration_s > 0.0 && duration_s <= MAX_DURATION_S) {
        return Err(PlanError::Duration);
    }
    let fine = |v: &Vector3<f32>| v.iter().all(|x| x.is_finite() && x.abs() <= MAX_DISTANCE_M);
    if !fine(to_ned_m) || !fine(&from.pos_ned_m) || !to_yaw_rad.is_finite() || !from.yaw_rad.is_finite() {
        return Err(PlanError::Position);
    }
    Ok(())
}

/// A planned segment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    start_us: u64,
    duration_s: f32,
    /// North, east, down, heading.
    coef: [[f32; 8]; 4],
}

impl Segment {
    /// From `from` at `start_us` to rest at `to_ned_m` with heading
    /// `to_yaw_rad` (the shorter way round) after `duration_s`.
    pub fn plan(
        start_us: u64,
        from: &Reference,
        to_ned_m: Vector3<f32>,
        to_yaw_rad: f32,
        duration_s: f32,
    ) -> Result<Self, PlanError> {
        check(from, &to_ned_m, to_yaw_rad, duration_s)?;
        let t = duration_s;
        let mut coef = [[0.0; 8]; 4];
        for (i, c) in coef.iter_mut().take(3).enumerate() {
            *c = axis(
                from.pos_ned_m[i],
                from.vel_ned_mps[i],
                from.acc_ned_mps2[i],
                to_ned_m[i],
                t,
            );
        }
        let yaw1 = from.yaw_rad + wrap(to_yaw_rad - from.yaw_rad);
        coef[3] = axis(from.yaw_rad, from.yaw_rate_radps, 0.0, yaw1, t);
        Ok(Self {
            start_us,
            duration_s,
            coef,
        })
    }

    /// From `from`'s position at `start_us` to `to_ned_m` along a straight
    /// line at constant velocity (the Crazyflie's "linear" `go_to`), the
    /// heading likewise; at rest after `duration_s`.
    pub fn linear(
        start_us: u64,
        from: &Reference,
        to_ned_m: Vector3<f32>,
        to_yaw_rad: f32,
        duration_s: f32,
    ) -> Result<Self, PlanError> {
        check(from, &to_ned_m, to_yaw_rad, duration_s)?;
        let yaw1 = from.yaw_rad + wrap(to_yaw_rad - from.yaw_rad);
        let ends = [
            (from.pos_ned_m[0], to_ned_m[0]),
            (from.pos_ned_m[1], to_ned_m[1]),
            (from.pos_ned_m[2], to_ned_m[2]),
            (from.yaw_rad, yaw1),
        ];
        Ok(Self {
            start_us,
            duration_s,
            coef: ends.map(|(a, b)| [a, b - a, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
        })
    }

    /// The reference at `now_us` (at rest at the goal after the end).
    pub fn eval(&self, now_us: u64) -> Reference {
        let t = now_us.saturating_sub(self.start_us) as f32 * 1e-6;
        let s = (t / self.duration_s).min(1.0);
        let (inv_t, inv_t2) = (1.0 / self.duration_s, 1.0 / (self.duration_s * self.duration_s));
        let mut r = Reference::at_rest(Vector3::zeros(), 0.0);
        for i in 0..3 {
            let [p, d, dd, _] = eval_poly(&self.coef[i], s);
            r.pos_ned_m[i] = p;
            r.vel_ned_mps[i] = d * inv_t;
            r.acc_ned_mps2[i] = dd * inv_t2;
        }
        let [y, dy, _, _] = eval_poly(&self.coef[3], s);
        r.yaw_rad = wrap(y);
        r.yaw_rate_radps = dy * inv_t;
        if s >= 1.0 {
            r.vel_ned_mps = Vector3::zeros();
            r.acc_ned_mps2 = Vector3::zeros();
            r.yaw_rate_radps = 0.0;
        }
        r
    }

    /// The segment has ended at `now_us`.
    pub fn finished(&self, now_us: u64) -> bool {
        now_us.saturating_sub(self.start_us) as f32 * 1e-6 >= self.duration_s
    }

    /// Its goal.
    pub fn goal(&self) -> Reference {
        self.eval(u64::MAX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rest-to-rest segment is the minimum-snap-like 35s⁴ − 84s⁵ +
    /// 70s⁶ − 20s⁷ of the textbooks (analytic): half way at s = ½, peak
    /// speed 35/16 · d/T there.
    #[test]
    fn rest_to_rest_is_the_analytic_septic() {
        let from = Reference::at_rest(Vector3::new(0.0, 0.0, -0.5), 0.0);
        let seg = Segment::plan(0, &from, Vector3::new(2.0, 0.0, -0.5), 0.0, 4.0).unwrap();
        let mid = seg.eval(2_000_000);
        assert!((mid.pos_ned_m[0] - 1.0).abs() < 1e-5, "{mid:?}");
        assert!((mid.vel_ned_mps[0] - 35.0 / 16.0 * 2.0 / 4.0).abs() < 1e-4, "{mid:?}");
        assert!(mid.acc_ned_mps2[0].abs() < 1e-4);
        let end = seg.eval(4_000_000);
        assert!((end.pos_ned_m[0] - 2.0).abs() < 1e-5);
        assert!(end.vel_ned_mps.norm() < 1e-6 && seg.finished(4_000_000) && !seg.finished(3_999_000));
    }

    /// Starting in motion, the segment keeps the start's position, velocity
    /// and acceleration (a smooth hand-over) and ends at rest.
    #[test]
    fn a_segment_starts_from_the_present_motion() {
        let mut from = Reference::at_rest(Vector3::new(1.0, 2.0, -1.0), 0.5);
        from.vel_ned_mps = Vector3::new(0.5, -0.2, 0.1);
        from.acc_ned_mps2 = Vector3::new(-0.3, 0.1, 0.0);
        let seg = Segment::plan(1_000, &from, Vector3::new(0.0, 0.0, -1.5), -3.0, 3.0).unwrap();
        let start = seg.eval(1_000);
        assert!((start.pos_ned_m - from.pos_ned_m).norm() < 1e-5);
        assert!((start.vel_ned_mps - from.vel_ned_mps).norm() < 1e-5);
        assert!((start.acc_ned_mps2 - from.acc_ned_mps2).norm() < 1e-4);
        // Near the end the speed and acceleration die out.
        let near = seg.eval(1_000 + 2_999_000);
        assert!(
            near.vel_ned_mps.norm() < 1e-3 && near.acc_ned_mps2.norm() < 1e-2,
            "{near:?}"
        );
        // Heading: from 0.5 to −3.0 the short way is through π (+2.78 rad).
        let goal = seg.goal();
        assert!((wrap(goal.yaw_rad - -3.0)).abs() < 1e-4);
        assert!(seg.eval(1_000 + 1_500_000).yaw_rad.abs() > 1.5);
    }

    #[test]
    fn absurd_segments_are_refused() {
        let from = Reference::at_rest(Vector3::zeros(), 0.0);
        let to = Vector3::new(1.0, 0.0, 0.0);
        for d in [0.0, -1.0, f32::NAN, f32::INFINITY, 1e6] {
            assert_eq!(Segment::plan(0, &from, to, 0.0, d), Err(PlanError::Duration));
        }
        for p in [Vector3::new(f32::NAN, 0.0, 0.0), Vector3::new(0.0, 2e3, 0.0)] {
            assert_eq!(Segment::plan(0, &from, p, 0.0, 1.0), Err(PlanError::Position));
        }
        assert_eq!(Segment::plan(0, &from, to, f32::NAN, 1.0), Err(PlanError::Position));
        assert_eq!(Segment::linear(0, &from, to, 0.0, 0.0), Err(PlanError::Duration));
        assert_eq!(
            Segment::linear(0, &from, Vector3::new(0.0, 2e3, 0.0), 0.0, 1.0),
            Err(PlanError::Position)
        );
    }

    /// A linear segment moves at constant velocity along the straight line.
    #[test]
    fn a_linear_segment_is_straight_at_constant_speed() {
        let from = Reference::at_rest(Vector3::new(0.0, 0.0, -1.0), 0.0);
        let seg = Segment::linear(0, &from, Vector3::new(2.0, 1.0, -1.0), 0.0, 2.0).unwrap();
        let mid = seg.eval(1_000_000);
        assert!((mid.pos_ned_m - Vector3::new(1.0, 0.5, -1.0)).norm() < 1e-6);
        assert!((mid.vel_ned_mps - Vector3::new(1.0, 0.5, 0.0)).norm() < 1e-6);
    }
}
