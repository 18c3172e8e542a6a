//! Uploaded trajectories, as the Crazyflie's high-level commander flies
//! them: a sequence of pieces, each four polynomials of degree 7 in the
//! piece's own time (north, east, down and heading; coefficients from the
//! constant up, seconds) and a duration. A trajectory is started with a
//! time scale (2: half speed), forwards or reversed, and optionally shifted
//! so that it starts where the vehicle's reference is (its position, and
//! its heading).
//!
//! The pieces are checked once, when the trajectory is built
//! ([`Trajectory::push`]): a coefficient that is not finite, a duration
//! that is not in (0, [`MAX_PIECE_S`]] s, or one piece more than
//! [`MAX_PIECES`] is refused by name, and the trajectory keeps the pieces
//! it had. A [`Flight`] owns its copy of the pieces, so nothing written
//! after it starts changes what it flies.
//!
//! Evaluation follows the Crazyflie's piecewise polynomials
//! (`piecewise.c`): piece by piece in the scaled time, position, velocity,
//! acceleration and jerk from one Horner pass, each derivative divided by
//! the time scale's power; reversed, the time runs back from the end and
//! the odd derivatives change sign; after the end, at rest at the end.
//! Every loop is bounded by [`MAX_PIECES`] and the degree.

use crate::planner::{eval_poly, Reference};
use nalgebra::Vector3;

/// Coefficients per polynomial (degree 7).
pub const COEFFICIENTS: usize = 8;
/// Most pieces one trajectory holds: the Crazyflie's trajectory memory
/// (4096 bytes) holds 31 uncompressed pieces of 132 bytes.
pub const MAX_PIECES: usize = 31;
/// Longest piece, s.
pub const MAX_PIECE_S: f32 = 1000.0;
/// Largest time scale (1000 times slower); the smallest is its inverse.
pub const MAX_TIME_SCALE: f32 = 1000.0;

/// Why a piece or a start was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrajectoryError {
    /// A coefficient of the piece with this index is NaN or infinite.
    NotFinite {
        /// The piece's index in the trajectory.
        piece: u8,
    },
    /// The piece's duration is not in (0, [`MAX_PIECE_S`]] s.
    Duration {
        /// The piece's index in the trajectory.
        piece: u8,
    },
    /// The trajectory already holds [`MAX_PIECES`] pieces.
    Full,
    /// The trajectory holds no piece.
    Empty,
    /// The time scale is not finite or not in
    /// [1/[`MAX_TIME_SCALE`], [`MAX_TIME_SCALE`]].
    TimeScale,
    /// The shift is not finite.
    Shift,
}

impl core::fmt::Display for TrajectoryError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            TrajectoryError::NotFinite { piece } => write!(f, "trajectory piece {piece}: a coefficient is not finite"),
            TrajectoryError::Duration { piece } => {
                write!(
                    f,
                    "trajectory piece {piece}: duration must be in (0, {}] s",
                    MAX_PIECE_S as u32
                )
            }
            TrajectoryError::Full => write!(f, "a trajectory holds at most {MAX_PIECES} pieces"),
            TrajectoryError::Empty => write!(f, "the trajectory has no piece"),
            TrajectoryError::TimeScale => {
                let s = MAX_TIME_SCALE as u32;
                write!(f, "time scale must be in [1/{s}, {s}]")
            }
            TrajectoryError::Shift => write!(f, "the trajectory's shift must be finite"),
        }
    }
}

/// One piece: north, east, down (m) and heading (rad) as polynomials of
/// the time since the piece began (s), coefficients from the constant up,
/// over `duration_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    /// `poly[axis][k]`: the coefficient of `tᵏ` of north, east, down, heading.
    pub poly: [[f32; COEFFICIENTS]; 4],
    /// Duration, s.
    pub duration_s: f32,
}

/// A point of a trajectory: the reference and its jerk.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Position, velocity, acceleration (NED) and heading with its rate.
    pub reference: Reference,
    /// Jerk, NED, m/s³.
    pub jerk_ned_mps3: Vector3<f32>,
}

impl Piece {
    /// The piece's index-`i` check ([`Trajectory::push`]).
    fn check(&self, i: u8) -> Result<(), TrajectoryError> {
        if !self.poly.iter().flatten().all(|c| c.is_finite()) {
            return Err(TrajectoryError::NotFinite { piece: i });
        }
        let d = self.duration_s;
        if !(d.is_finite() && d > 0.0 && d <= MAX_PIECE_S) {
            return Err(TrajectoryError::Duration { piece: i });
        }
        Ok(())
    }

    /// Value and derivatives (per second of the piece's own time) of every
    /// axis at `t` s into it.
    fn eval(&self, t: f32) -> [[f32; 4]; 4] {
        self.poly.map(|c| eval_poly(&c, t))
    }
}

/// Up to [`MAX_PIECES`] checked pieces, flown one after the other.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trajectory {
    pieces: [Piece; MAX_PIECES],
    len: u8,
}

impl Default for Trajectory {
    fn default() -> Self {
        Self::new()
    }
}

impl Trajectory {
    /// No piece.
    pub const fn new() -> Self {
        Self {
            pieces: [Piece {
                poly: [[0.0; COEFFICIENTS]; 4],
                duration_s: 0.0,
            }; MAX_PIECES],
            len: 0,
        }
    }

    /// Appends `piece` after checking it; on error the trajectory is as it was.
    pub fn push(&mut self, piece: Piece) -> Result<(), TrajectoryError> {
        let i = usize::from(self.len);
        if i >= MAX_PIECES {
            return Err(TrajectoryError::Full);
        }
        piece.check(self.len)?;
        self.pieces[i] = piece;
        self.len += 1;
        Ok(())
    }

    /// The pieces held.
    pub fn pieces(&self) -> &[Piece] {
        &self.pieces[..usize::from(self.len)]
    }

    /// Total duration at time scale 1, s.
    pub fn duration_s(&self) -> f32 {
        self.pieces().iter().map(|p| p.duration_s).sum()
    }

    /// Value and derivatives of every axis at `t` s from the start (time
    /// scale 1), clamped to [0, end]; after the end, the end's value with
    /// every derivative zero.
    fn eval(&self, t: f32) -> [[f32; 4]; 4] {
        let mut left = t.max(0.0);
        for p in self.pieces() {
            if left <= p.duration_s {
                return p.eval(left);
            }
            left -= p.duration_s;
        }
        let Some(last) = self.pieces().last() else {
            return [[0.0; 4]; 4];
        };
        last.eval(last.duration_s).map(|a| [a[0], 0.0, 0.0, 0.0])
    }
}

/// How a trajectory is flown ([`Flight::start`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StartOptions {
    /// Time scale: 1 as planned, 2 at half speed.
    pub time_scale: f32,
    /// Flown from its end back to its start.
    pub reversed: bool,
    /// Added to every position, NED, m (a relative start: where the
    /// reference is, minus where the trajectory starts).
    pub shift_ned_m: Vector3<f32>,
    /// Added to the heading, rad.
    pub shift_yaw_rad: f32,
}

/// A trajectory being flown: its own copy of the pieces, when it started
/// and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flight {
    trajectory: Trajectory,
    start_us: u64,
    options: StartOptions,
}

impl Flight {
    /// Starts `trajectory` at `start_us` with `options`, refused if it has
    /// no piece or the options are absurd.
    pub fn start(trajectory: &Trajectory, start_us: u64, options: StartOptions) -> Result<Self, TrajectoryError> {
        if trajectory.pieces().is_empty() {
            return Err(TrajectoryError::Empty);
        }
        let s = options.time_scale;
        if !(s.is_finite() && (1.0 / MAX_TIME_SCALE..=MAX_TIME_SCALE).contains(&s)) {
            return Err(TrajectoryError::TimeScale);
        }
        if !(options.shift_ned_m.iter().all(|v| v.is_finite()) && options.shift_yaw_rad.is_finite()) {
            return Err(TrajectoryError::Shift);
        }
        Ok(Self {
            trajectory: *trajectory,
            start_us,
            options,
        })
    }

    /// Where the trajectory starts when flown (its first point, or its
    /// last reversed), before any shift: what a relative start subtracts.
    pub fn first_point(trajectory: &Trajectory, reversed: bool) -> Option<Reference> {
        let first = trajectory.pieces().first()?;
        let e = if reversed {
            trajectory.eval(trajectory.duration_s())
        } else {
            first.eval(0.0)
        };
        Some(Reference::at_rest(Vector3::new(e[0][0], e[1][0], e[2][0]), e[3][0]))
    }

    /// Flown time at `now_us`, scaled to the trajectory's own, s.
    fn own_time(&self, now_us: u64) -> f32 {
        now_us.saturating_sub(self.start_us) as f32 * 1e-6 / self.options.time_scale
    }

    /// The trajectory at `now_us` (at rest at its end after it).
    pub fn sample(&self, now_us: u64) -> Sample {
        let t = self.own_time(now_us);
        let total = self.trajectory.duration_s();
        let (e, sign) = if self.options.reversed {
            let mut e = self.trajectory.eval(total - t.min(total));
            if t >= total {
                e = e.map(|a| [a[0], 0.0, 0.0, 0.0]);
            }
            (e, -1.0)
        } else {
            (self.trajectory.eval(t), 1.0)
        };
        // d/dt of the flown time: ±1/scale per derivative order.
        let k = sign / self.options.time_scale;
        let (k2, k3) = (k * k, k * k * k);
        let o = &self.options;
        let mut r = Reference::at_rest(Vector3::zeros(), 0.0);
        let mut jerk = Vector3::zeros();
        for i in 0..3 {
            r.pos_ned_m[i] = e[i][0] + o.shift_ned_m[i];
            r.vel_ned_mps[i] = e[i][1] * k;
            r.acc_ned_mps2[i] = e[i][2] * k2;
            jerk[i] = e[i][3] * k3;
        }
        r.yaw_rad = crate::planner::wrap(e[3][0] + o.shift_yaw_rad);
        r.yaw_rate_radps = e[3][1] * k;
        Sample {
            reference: r,
            jerk_ned_mps3: jerk,
        }
    }

    /// The flight has reached its end at `now_us`.
    pub fn finished(&self, now_us: u64) -> bool {
        self.own_time(now_us) >= self.trajectory.duration_s()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn piece(x: [f32; 8], yaw: [f32; 8], duration_s: f32) -> Piece {
        Piece {
            poly: [x, [0.0; 8], [0.0; 8], yaw],
            duration_s,
        }
    }

    fn one(p: Piece) -> Trajectory {
        let mut t = Trajectory::new();
        t.push(p).unwrap();
        t
    }

    const AS_PLANNED: StartOptions = StartOptions {
        time_scale: 1.0,
        reversed: false,
        shift_ned_m: Vector3::new(0.0, 0.0, 0.0),
        shift_yaw_rad: 0.0,
    };

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= 1e-5 * (1.0 + b.abs())
    }

    /// x(t) = t³ − t²: value and derivatives against the analytic ones,
    /// and at half speed each derivative of order n divided by 2ⁿ.
    #[test]
    fn a_piece_is_its_polynomial_and_time_scales_its_derivatives() {
        let x = |t: f32| [t * t * t - t * t, 3.0 * t * t - 2.0 * t, 6.0 * t - 2.0, 6.0];
        let tr = one(piece([0.0, 0.0, -1.0, 1.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 2.0));
        for scale in [1.0f32, 2.0, 0.5] {
            let f = Flight::start(
                &tr,
                1_000_000,
                StartOptions {
                    time_scale: scale,
                    ..AS_PLANNED
                },
            )
            .unwrap();
            for t in [0.0f32, 0.3, 1.0, 1.7] {
                let s = f.sample(1_000_000 + (t * scale * 1e6) as u64);
                let want = x(t);
                let r = &s.reference;
                assert!(
                    close(r.pos_ned_m[0], want[0]),
                    "scale {scale} t {t}: {}",
                    r.pos_ned_m[0]
                );
                assert!(
                    close(r.vel_ned_mps[0], want[1] / scale),
                    "scale {scale} t {t}: {}",
                    r.vel_ned_mps[0]
                );
                assert!(
                    close(r.acc_ned_mps2[0], want[2] / (scale * scale)),
                    "scale {scale} t {t}"
                );
                assert!(
                    close(s.jerk_ned_mps3[0], want[3] / (scale * scale * scale)),
                    "scale {scale} t {t}"
                );
                assert_eq!((r.pos_ned_m[1], r.pos_ned_m[2]), (0.0, 0.0));
            }
        }
    }

    /// Each piece runs on its own clock from 0; after the last, the
    /// trajectory rests at its end.
    #[test]
    fn pieces_follow_each_other_and_the_end_is_held() {
        let mut tr = Trajectory::new();
        // x = t over 1 s, then x = 1 + 2t over 0.5 s.
        tr.push(piece([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 1.0))
            .unwrap();
        tr.push(piece([1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 0.5))
            .unwrap();
        assert!(close(tr.duration_s(), 1.5));
        let f = Flight::start(&tr, 0, AS_PLANNED).unwrap();
        let at = |t: f32| f.sample((t * 1e6) as u64).reference;
        assert!(close(at(0.5).pos_ned_m[0], 0.5) && close(at(0.5).vel_ned_mps[0], 1.0));
        assert!(close(at(1.25).pos_ned_m[0], 1.5) && close(at(1.25).vel_ned_mps[0], 2.0));
        assert!(!f.finished(1_400_000) && f.finished(1_501_000));
        let end = at(5.0);
        assert!(close(end.pos_ned_m[0], 2.0), "{}", end.pos_ned_m[0]);
        assert_eq!(end.vel_ned_mps, Vector3::zeros());
        assert_eq!(end.acc_ned_mps2, Vector3::zeros());
    }

    /// Reversed, the trajectory runs from its end to its start: positions
    /// mirrored in time, velocity and jerk negated, acceleration not.
    #[test]
    fn reversed_runs_back_with_the_odd_derivatives_negated() {
        // x = t² over 2 s.
        let tr = one(piece([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 2.0));
        let f = Flight::start(
            &tr,
            0,
            StartOptions {
                reversed: true,
                ..AS_PLANNED
            },
        )
        .unwrap();
        for t in [0.0f32, 0.5, 1.5] {
            let r = f.sample((t * 1e6) as u64).reference;
            let u = 2.0 - t;
            assert!(close(r.pos_ned_m[0], u * u), "t {t}: {}", r.pos_ned_m[0]);
            assert!(close(r.vel_ned_mps[0], -2.0 * u), "t {t}: {}", r.vel_ned_mps[0]);
            assert!(close(r.acc_ned_mps2[0], 2.0), "t {t}");
        }
        let end = f.sample(3_000_000).reference;
        assert!(close(end.pos_ned_m[0], 0.0) && end.vel_ned_mps[0] == 0.0 && end.acc_ned_mps2[0] == 0.0);
        let first = Flight::first_point(&tr, true).unwrap();
        assert!(close(first.pos_ned_m[0], 4.0));
    }

    /// A relative start shifts every position and the heading; the heading
    /// is wrapped into (−π, π] and its rate is the polynomial's.
    #[test]
    fn a_shift_moves_the_trajectory_and_its_heading() {
        use core::f32::consts::PI;
        // Heading 3 + t rad: past π after 0.14 s.
        let tr = one(piece(
            [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [3.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            1.0,
        ));
        let f = Flight::start(
            &tr,
            0,
            StartOptions {
                shift_ned_m: Vector3::new(-1.0, 2.0, -0.5),
                shift_yaw_rad: 0.5,
                ..AS_PLANNED
            },
        )
        .unwrap();
        let r = f.sample(500_000).reference;
        assert_eq!(r.pos_ned_m, Vector3::new(0.0, 2.0, -0.5));
        assert!(close(r.yaw_rad, 4.0 - 2.0 * PI), "{}", r.yaw_rad);
        assert!(close(r.yaw_rate_radps, 1.0));
    }

    /// Bad pieces and starts are refused by name, and a refused piece
    /// leaves the trajectory as it was.
    #[test]
    fn absurd_pieces_and_starts_are_refused() {
        let good = piece([0.0; 8], [0.0; 8], 1.0);
        let mut tr = Trajectory::new();
        tr.push(good).unwrap();
        let mut nan = good;
        nan.poly[2][5] = f32::NAN;
        assert_eq!(tr.push(nan), Err(TrajectoryError::NotFinite { piece: 1 }));
        let mut inf = good;
        inf.poly[3][0] = f32::INFINITY;
        assert_eq!(tr.push(inf), Err(TrajectoryError::NotFinite { piece: 1 }));
        for d in [0.0, -1.0, f32::NAN, f32::INFINITY, MAX_PIECE_S * 2.0] {
            let mut p = good;
            p.duration_s = d;
            assert_eq!(tr.push(p), Err(TrajectoryError::Duration { piece: 1 }), "{d}");
        }
        assert_eq!(tr.pieces().len(), 1);
        for _ in 1..MAX_PIECES {
            tr.push(good).unwrap();
        }
        assert_eq!(tr.push(good), Err(TrajectoryError::Full));
        assert_eq!(tr.pieces().len(), MAX_PIECES);
        assert_eq!(
            Flight::start(&Trajectory::new(), 0, AS_PLANNED),
            Err(TrajectoryError::Empty)
        );
        for s in [0.0, -1.0, f32::NAN, 1e-4, 1e4] {
            let o = StartOptions {
                time_scale: s,
                ..AS_PLANNED
            };
            assert_eq!(Flight::start(&tr, 0, o), Err(TrajectoryError::TimeScale), "{s}");
        }
        let o = StartOptions {
            shift_ned_m: Vector3::new(0.0, f32::NAN, 0.0),
            ..AS_PLANNED
        };
        assert_eq!(Flight::start(&tr, 0, o), Err(TrajectoryError::Shift));
        // Every refusal says what was wrong.
        assert!(TrajectoryError::Duration { piece: 3 }.to_string().contains("piece 3"));
    }

    /// A flight flies its own copy: pieces pushed after it started do not
    /// change it.
    #[test]
    fn a_flight_keeps_the_pieces_it_started_with() {
        let mut tr = one(piece([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 1.0));
        let f = Flight::start(&tr, 0, AS_PLANNED).unwrap();
        let before = f.sample(2_000_000);
        tr.push(piece([5.0; 8], [0.0; 8], 1.0)).unwrap();
        assert_eq!(f.sample(2_000_000), before);
        assert!(close(before.reference.pos_ned_m[0], 1.0));
    }
}
