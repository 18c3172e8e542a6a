//! Uploaded trajectories, as the Crazyflie's high-level commander flies
//! them: its trajectory memory ([`TrajectoryMemory`], 4096 bytes, which a
//! client writes in chunks), trajectories defined in it by id (an offset
//! and a number of pieces), and a [`Flight`] of one of them.
//!
//! A piece is the Crazyflie's uncompressed `poly4d`: four polynomials of
//! degree 7 in the piece's own time (x, y, z and yaw, coefficients from the
//! constant up, 8 little-endian `f32` each) and its duration (`f32`, s),
//! 132 bytes, in the Crazyflie's world frame (x forward, y left, z up; yaw
//! counter-clockwise, rad). It is flown in NED: north = x, east = −y,
//! down = −z, heading = −yaw ([`AXIS_SIGNS`]).
//!
//! A trajectory is started with a time scale (2: half speed), forwards or
//! reversed, and optionally relative: moved so that it starts where the
//! reference flown is, and (relative yaw) turned about its start so that
//! its heading starts as the reference's does.
//!
//! What flies is never changed under it: while a flight is under way the
//! memory refuses writes ([`TrajectoryError::Flying`], decided by
//! [`crate::client::ClientCommander`]); a flight keeps its definition's
//! offset and pieces, so a new definition of its id changes nothing flown.
//! The pieces are checked when a trajectory is defined and again when it
//! starts: a piece past the memory's end, a coefficient that is not finite,
//! a duration that is not in (0, [`MAX_PIECE_S`]] s, or a piece that starts
//! farther than the planner's [`MAX_DISTANCE_M`] is refused by name.
//! Whether each word of the memory is a finite `f32` is kept as the memory
//! is written, so a check reads one bit a word, not the word.
//!
//! Evaluation follows the Crazyflie's piecewise polynomials
//! (`piecewise.c`): piece by piece in the scaled time, position, velocity,
//! acceleration and jerk from one Horner pass, each derivative divided by
//! the time scale's power; reversed, the time runs back from the end and
//! the odd derivatives change sign; after the end, at rest at the end.
//! Every loop is bounded by [`MAX_PIECES`] and the degree.

use crate::planner::{eval_poly, wrap, Reference, MAX_DISTANCE_M};
use nalgebra::Vector3;

/// Coefficients per polynomial (degree 7).
pub const COEFFICIENTS: usize = 8;
/// Bytes of one uncompressed piece: 4 × 8 coefficients and the duration,
/// `f32` each.
pub const PIECE_BYTES: usize = (4 * COEFFICIENTS + 1) * 4;
/// The trajectory memory's size, bytes: the Crazyflie's
/// (`TRAJECTORY_MEMORY_SIZE`).
pub const MEMORY_BYTES: usize = 4096;
/// Most pieces one trajectory holds: as many as the memory holds (31).
pub const MAX_PIECES: usize = MEMORY_BYTES / PIECE_BYTES;
/// Trajectory ids: 0 to this less one (the Crazyflie's
/// `NUM_TRAJECTORY_DEFINITIONS`).
pub const DEFINITIONS: usize = 10;
/// Longest piece, s.
pub const MAX_PIECE_S: f32 = 1000.0;
/// Largest time scale (1000 times slower); the smallest is its inverse.
pub const MAX_TIME_SCALE: f32 = 1000.0;
/// North, east, down and heading of a piece's x, y, z and yaw: the
/// Crazyflie's world frame (x forward, y left, z up, yaw counter-clockwise)
/// in NED.
pub const AXIS_SIGNS: [f32; 4] = [1.0, -1.0, -1.0, -1.0];

const WORDS: usize = MEMORY_BYTES / 4;

/// Why a write, a definition or a start was refused.
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
    /// The piece starts farther than [`MAX_DISTANCE_M`] from the origin.
    Position {
        /// The piece's index in the trajectory.
        piece: u8,
    },
    /// A write, read or definition reaches past the memory's end, or the
    /// definition holds no piece.
    PastTheEnd,
    /// A definition's offset is not a multiple of 4 bytes.
    Alignment,
    /// A write while a trajectory flies.
    Flying,
    /// The trajectory id is not below [`DEFINITIONS`].
    Id,
    /// No trajectory is defined with this id.
    Undefined,
    /// The trajectory's type or location is not the uncompressed `poly4d`
    /// in this memory (compressed trajectories are not flown yet).
    Kind,
    /// The time scale is not finite or not in
    /// [1/[`MAX_TIME_SCALE`], [`MAX_TIME_SCALE`]].
    TimeScale,
    /// The reference a relative start starts from is not finite.
    Shift,
}

impl core::fmt::Display for TrajectoryError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        // Limits as integers: a float's `Display` would link core's float
        // formatting into the images.
        match self {
            TrajectoryError::NotFinite { piece } => write!(f, "trajectory piece {piece}: a coefficient is not finite"),
            TrajectoryError::Duration { piece } => {
                let max = MAX_PIECE_S as u32;
                write!(f, "trajectory piece {piece}: duration must be in (0, {max}] s")
            }
            TrajectoryError::Position { piece } => {
                let max = MAX_DISTANCE_M as u32;
                write!(f, "trajectory piece {piece}: starts farther than {max} m")
            }
            TrajectoryError::PastTheEnd => write!(f, "past the trajectory memory's {MEMORY_BYTES} bytes"),
            TrajectoryError::Alignment => write!(f, "a trajectory's offset must be a multiple of 4 bytes"),
            TrajectoryError::Flying => write!(f, "a trajectory flies from the memory"),
            TrajectoryError::Id => write!(f, "trajectory ids are 0 to {}", DEFINITIONS - 1),
            TrajectoryError::Undefined => write!(f, "no trajectory with that id"),
            TrajectoryError::Kind => write!(f, "only uncompressed poly4d trajectories in memory"),
            TrajectoryError::TimeScale => {
                let s = MAX_TIME_SCALE as u32;
                write!(f, "time scale must be in [1/{s}, {s}]")
            }
            TrajectoryError::Shift => write!(f, "the trajectory's start is not finite"),
        }
    }
}

/// One piece in NED: north, east, down (m) and heading (rad) as
/// polynomials of the time since the piece began (s), coefficients from
/// the constant up, over `duration_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Piece {
    /// `poly[axis][k]`: the coefficient of `tᵏ` of north, east, down, heading.
    pub poly: [[f32; COEFFICIENTS]; 4],
    /// Duration, s.
    pub duration_s: f32,
}

impl Piece {
    /// The piece as the Crazyflie's memory holds it (its frame, little-endian).
    pub fn to_bytes(&self) -> [u8; PIECE_BYTES] {
        let mut b = [0u8; PIECE_BYTES];
        for (axis, (c, sign)) in self.poly.iter().zip(AXIS_SIGNS).enumerate() {
            for (k, v) in c.iter().enumerate() {
                let at = (axis * COEFFICIENTS + k) * 4;
                b[at..at + 4].copy_from_slice(&(v * sign).to_le_bytes());
            }
        }
        b[PIECE_BYTES - 4..].copy_from_slice(&self.duration_s.to_le_bytes());
        b
    }
}

/// The `f32` at byte `at` of `bytes` (0 past its end).
fn f32_at(bytes: &[u8], at: usize) -> f32 {
    match bytes.get(at..at + 4) {
        Some(&[a, b, c, d]) => f32::from_le_bytes([a, b, c, d]),
        _ => 0.0,
    }
}

/// A trajectory defined in the memory: its first byte and its pieces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Definition {
    offset: u16,
    pieces: u8,
}

impl Definition {
    /// `pieces` pieces from byte `offset`, refused if they reach past the
    /// memory's end, there are none, or the offset is not word-aligned.
    pub fn new(offset: u32, pieces: u8) -> Result<Self, TrajectoryError> {
        let end = u64::from(offset) + u64::from(pieces) * PIECE_BYTES as u64;
        if pieces == 0 || end > MEMORY_BYTES as u64 {
            return Err(TrajectoryError::PastTheEnd);
        }
        if !offset.is_multiple_of(4) {
            return Err(TrajectoryError::Alignment);
        }
        Ok(Self {
            offset: offset as u16,
            pieces,
        })
    }

    /// The number of pieces.
    pub fn pieces(&self) -> u8 {
        self.pieces
    }

    fn at(&self, i: usize) -> usize {
        usize::from(self.offset) + i * PIECE_BYTES
    }

    fn duration_of(&self, memory: &[u8], i: usize) -> f32 {
        f32_at(memory, self.at(i) + PIECE_BYTES - 4)
    }

    /// Value and derivatives (per second of the piece's own time) of
    /// `axis` (NED, [`AXIS_SIGNS`]) of piece `i` of `memory` at `t` s into
    /// it (zeros past the memory's end). One copy, not one per axis.
    #[inline(never)]
    fn axis_at(&self, memory: &[u8], i: usize, axis: usize, t: f32) -> [f32; 4] {
        let at = self.at(i) + axis * COEFFICIENTS * 4;
        let mut c = [0.0; COEFFICIENTS];
        for (k, v) in c.iter_mut().enumerate() {
            *v = f32_at(memory, at + 4 * k);
        }
        let sign = AXIS_SIGNS.get(axis).copied().unwrap_or(1.0);
        eval_poly(&c, t).map(|x| sign * x)
    }

    /// Value and derivatives of every axis at `t` s from the start (time
    /// scale 1), clamped to [0, end]; after the end, the end's value with
    /// every derivative zero.
    fn eval(&self, memory: &[u8], t: f32) -> [[f32; 4]; 4] {
        let n = usize::from(self.pieces);
        let (mut left, mut piece, mut after) = (t.max(0.0), n.saturating_sub(1), true);
        for i in 0..n {
            let d = self.duration_of(memory, i);
            if left <= d {
                (piece, after) = (i, false);
                break;
            }
            left -= d;
        }
        if after {
            left = self.duration_of(memory, piece);
        }
        let mut e = [[0.0; 4]; 4];
        for (axis, a) in e.iter_mut().enumerate() {
            *a = self.axis_at(memory, piece, axis, left);
            if after {
                a[1..].fill(0.0);
            }
        }
        e
    }
}

/// The Crazyflie's trajectory memory and the trajectories defined in it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectoryMemory {
    bytes: [u8; MEMORY_BYTES],
    /// Bit `w % 32` of word `w / 32`: the memory's word `w` (bytes 4w to
    /// 4w + 3) is not a finite `f32`.
    not_finite: [u32; WORDS / 32],
    definitions: [Option<Definition>; DEFINITIONS],
}

impl Default for TrajectoryMemory {
    fn default() -> Self {
        Self::new()
    }
}

impl TrajectoryMemory {
    /// Zeros, no trajectory defined.
    pub const fn new() -> Self {
        Self {
            bytes: [0; MEMORY_BYTES],
            not_finite: [0; WORDS / 32],
            definitions: [None; DEFINITIONS],
        }
    }

    /// The memory's bytes: what flights evaluate.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// Writes `data` from byte `addr`, refused (and nothing written) past
    /// the end. Whether a flight forbids it is the caller's to check
    /// ([`crate::client::ClientCommander::write_trajectory_memory`]).
    pub fn write(&mut self, addr: u32, data: &[u8]) -> Result<(), TrajectoryError> {
        if u64::from(addr) + data.len() as u64 > MEMORY_BYTES as u64 {
            return Err(TrajectoryError::PastTheEnd);
        }
        let at = addr as usize;
        self.bytes[at..at + data.len()].copy_from_slice(data);
        for w in at / 4..(at + data.len()).div_ceil(4) {
            let bad = !f32_at(&self.bytes, 4 * w).is_finite();
            let (word, bit) = (w / 32, 1u32 << (w % 32));
            if bad {
                self.not_finite[word] |= bit;
            } else {
                self.not_finite[word] &= !bit;
            }
        }
        Ok(())
    }

    /// `len` bytes from `addr`, refused past the end.
    pub fn read(&self, addr: u32, len: usize) -> Result<&[u8], TrajectoryError> {
        if u64::from(addr) + len as u64 > MEMORY_BYTES as u64 {
            return Err(TrajectoryError::PastTheEnd);
        }
        let at = addr as usize;
        Ok(&self.bytes[at..at + len])
    }

    /// Defines trajectory `id` as `def`, after checking its pieces as they
    /// stand ([`TrajectoryMemory::check`]).
    pub fn define(&mut self, id: u8, def: Definition) -> Result<(), TrajectoryError> {
        let slot = self.definitions.get_mut(usize::from(id)).ok_or(TrajectoryError::Id)?;
        *slot = None;
        self.check(&def)?;
        self.definitions[usize::from(id)] = Some(def);
        Ok(())
    }

    /// Trajectory `id`'s definition.
    pub fn definition(&self, id: u8) -> Result<Definition, TrajectoryError> {
        let slot = self.definitions.get(usize::from(id)).ok_or(TrajectoryError::Id)?;
        slot.ok_or(TrajectoryError::Undefined)
    }

    /// Refuses `def` if one of its pieces holds a coefficient that is not
    /// finite, a duration out of (0, [`MAX_PIECE_S`]] or a start farther
    /// than [`MAX_DISTANCE_M`]; otherwise its duration at time scale 1, s.
    pub fn check(&self, def: &Definition) -> Result<f32, TrajectoryError> {
        let first = usize::from(def.offset) / 4;
        if let Some(w) = self.first_not_finite(first, usize::from(def.pieces) * PIECE_BYTES / 4) {
            let piece = ((w - first) / (PIECE_BYTES / 4)) as u8;
            return Err(TrajectoryError::NotFinite { piece });
        }
        let mut total = 0.0;
        for i in 0..usize::from(def.pieces) {
            let piece = i as u8;
            let d = def.duration_of(&self.bytes, i);
            if !(d > 0.0 && d <= MAX_PIECE_S) {
                return Err(TrajectoryError::Duration { piece });
            }
            for axis in 0..3 {
                let c0 = f32_at(&self.bytes, def.at(i) + axis * COEFFICIENTS * 4);
                if c0.abs() > MAX_DISTANCE_M {
                    return Err(TrajectoryError::Position { piece });
                }
            }
            total += d;
        }
        Ok(total)
    }
}

impl TrajectoryMemory {
    /// The first of the `words` words from word `first` that is not a
    /// finite `f32`, if any: 32 words a test, at most
    /// [`MEMORY_BYTES`] / 128 + 1 tests.
    fn first_not_finite(&self, first: usize, words: usize) -> Option<usize> {
        let end = (first + words).min(WORDS);
        let mut w = first;
        while w < end {
            let bit = w % 32;
            let take = (32 - bit).min(end - w);
            let mask = if take == 32 {
                u32::MAX
            } else {
                ((1u32 << take) - 1) << bit
            };
            let bad = self.not_finite[w / 32] & mask;
            if bad != 0 {
                return Some(w - bit + bad.trailing_zeros() as usize);
            }
            w += take;
        }
        None
    }
}

/// How a trajectory is started (the Crazyflie's `START_TRAJECTORY`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StartOptions {
    /// Time scale: 1 as planned, 2 at half speed.
    pub time_scale: f32,
    /// Flown from its end back to its start.
    pub reversed: bool,
    /// Moved to start where the reference flown is.
    pub relative_position: bool,
    /// With a relative position: turned about its start so that its
    /// heading starts as the reference's.
    pub relative_yaw: bool,
}

/// A point of a trajectory: the reference and its jerk.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// Position, velocity, acceleration (NED) and heading with its rate.
    pub reference: Reference,
    /// Jerk, NED, m/s³.
    pub jerk_ned_mps3: Vector3<f32>,
}

/// What a flight is evaluated from: a vehicle's trajectory memory, or none.
pub trait Trajectories {
    /// `flight` at `now_us`.
    fn sample(&self, flight: &Flight, now_us: u64) -> Sample;
}

impl Trajectories for TrajectoryMemory {
    fn sample(&self, flight: &Flight, now_us: u64) -> Sample {
        flight.sample(&self.bytes, now_us)
    }
}

/// A memory some vehicles have: a PX4 vehicle's modes fly one only when
/// its host hands one over ([`crate::modes::ModeCommander::fly_trajectory`]).
impl<T: Trajectories + ?Sized> Trajectories for Option<&T> {
    fn sample(&self, flight: &Flight, now_us: u64) -> Sample {
        match self {
            Some(m) => m.sample(flight, now_us),
            None => NoTrajectories.sample(flight, now_us),
        }
    }
}

/// No trajectory memory (a PX4 vehicle's modes on the images): no flight starts without
/// one, and none is evaluated (one would rest where it started), so a
/// vehicle without one links no evaluation.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoTrajectories;

impl Trajectories for NoTrajectories {
    fn sample(&self, flight: &Flight, _now_us: u64) -> Sample {
        Sample {
            reference: Reference::at_rest(flight.origin_ned_m + flight.shift_ned_m, flight.turn_rad),
            jerk_ned_mps3: Vector3::zeros(),
        }
    }
}

/// A trajectory being flown: its definition, when it started and how.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flight {
    def: Definition,
    start_us: u64,
    time_scale: f32,
    reversed: bool,
    duration_s: f32,
    /// Where the trajectory starts as written (NED, m): what it turns about.
    origin_ned_m: Vector3<f32>,
    /// Added to every position, NED, m.
    shift_ned_m: Vector3<f32>,
    /// Added to the heading, and the turn about the origin, rad.
    turn_rad: f32,
    turn_cos_sin: [f32; 2],
}

impl Flight {
    /// Starts trajectory `id` of `memory` at `start_us` with `options`; a
    /// relative start starts from `from`, the reference flown. Refused if
    /// the trajectory is undefined, its pieces do not pass
    /// [`TrajectoryMemory::check`] as they stand, or the options are absurd.
    pub fn start(
        memory: &TrajectoryMemory,
        id: u8,
        start_us: u64,
        options: StartOptions,
        from: &Reference,
    ) -> Result<Self, TrajectoryError> {
        let def = memory.definition(id)?;
        let duration_s = memory.check(&def)?;
        let s = options.time_scale;
        if !(s.is_finite() && (1.0 / MAX_TIME_SCALE..=MAX_TIME_SCALE).contains(&s)) {
            return Err(TrajectoryError::TimeScale);
        }
        // Where it starts: the first piece's constant terms, or reversed its end.
        let first = if options.reversed {
            def.eval(&memory.bytes, duration_s).map(|a| a[0])
        } else {
            let at = |axis: usize| AXIS_SIGNS[axis] * f32_at(&memory.bytes, def.at(0) + axis * COEFFICIENTS * 4);
            [at(0), at(1), at(2), at(3)]
        };
        let origin_ned_m = Vector3::new(first[0], first[1], first[2]);
        let (mut shift_ned_m, mut turn_rad) = (Vector3::zeros(), 0.0);
        if options.relative_position {
            if !(from.pos_ned_m.iter().all(|v| v.is_finite()) && from.yaw_rad.is_finite()) {
                return Err(TrajectoryError::Shift);
            }
            shift_ned_m = from.pos_ned_m - origin_ned_m;
            if options.relative_yaw {
                turn_rad = wrap(from.yaw_rad - first[3]);
            }
        }
        Ok(Self {
            def,
            start_us,
            time_scale: s,
            reversed: options.reversed,
            duration_s,
            origin_ned_m,
            shift_ned_m,
            turn_rad,
            turn_cos_sin: if turn_rad == 0.0 {
                [1.0, 0.0]
            } else {
                [libm::cosf(turn_rad), libm::sinf(turn_rad)]
            },
        })
    }

    /// Flown time at `now_us`, scaled to the trajectory's own, s.
    fn own_time(&self, now_us: u64) -> f32 {
        now_us.saturating_sub(self.start_us) as f32 * 1e-6 / self.time_scale
    }

    /// A horizontal NED vector turned by the flight's turn (clockwise seen
    /// from above, as headings turn).
    fn turned(&self, v: Vector3<f32>) -> Vector3<f32> {
        let [c, s] = self.turn_cos_sin;
        Vector3::new(c * v[0] - s * v[1], s * v[0] + c * v[1], v[2])
    }

    /// The trajectory at `now_us` (at rest at its end after it), evaluated
    /// from `memory`'s bytes ([`TrajectoryMemory::bytes`]).
    pub fn sample(&self, memory: &[u8], now_us: u64) -> Sample {
        let t = self.own_time(now_us);
        let total = self.duration_s;
        let (e, sign) = if self.reversed {
            let mut e = self.def.eval(memory, total - t.min(total));
            if t >= total {
                e = e.map(|a| [a[0], 0.0, 0.0, 0.0]);
            }
            (e, -1.0)
        } else {
            (self.def.eval(memory, t), 1.0)
        };
        // d/dt of the flown time: ±1/scale per derivative order.
        let k = sign / self.time_scale;
        let (k2, k3) = (k * k, k * k * k);
        let axis = |j: usize| Vector3::new(e[0][j], e[1][j], e[2][j]);
        let pos = self.origin_ned_m + self.shift_ned_m + self.turned(axis(0) - self.origin_ned_m);
        Sample {
            reference: Reference {
                pos_ned_m: pos,
                vel_ned_mps: self.turned(axis(1) * k),
                acc_ned_mps2: self.turned(axis(2) * k2),
                yaw_rad: wrap(e[3][0] + self.turn_rad),
                yaw_rate_radps: e[3][1] * k,
            },
            jerk_ned_mps3: self.turned(axis(3) * k3),
        }
    }

    /// The flight has reached its end at `now_us`.
    pub fn finished(&self, now_us: u64) -> bool {
        self.own_time(now_us) >= self.duration_s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::f32::consts::{FRAC_PI_2, PI};

    /// A piece in NED with `north` and `heading` polynomials, the others 0.
    fn piece(north: [f32; 8], heading: [f32; 8], duration_s: f32) -> Piece {
        Piece {
            poly: [north, [0.0; 8], [0.0; 8], heading],
            duration_s,
        }
    }

    /// `pieces` written from byte 0 in cflib's 24-byte chunks and defined
    /// as trajectory 0.
    fn memory(pieces: &[Piece]) -> TrajectoryMemory {
        let mut m = TrajectoryMemory::new();
        let bytes: Vec<u8> = pieces.iter().flat_map(|p| p.to_bytes()).collect();
        for (i, chunk) in bytes.chunks(24).enumerate() {
            m.write((i * 24) as u32, chunk).unwrap();
        }
        m.define(0, Definition::new(0, pieces.len() as u8).unwrap()).unwrap();
        m
    }

    const AS_PLANNED: StartOptions = StartOptions {
        time_scale: 1.0,
        reversed: false,
        relative_position: false,
        relative_yaw: false,
    };

    fn start(m: &TrajectoryMemory, options: StartOptions) -> Result<Flight, TrajectoryError> {
        Flight::start(m, 0, 0, options, &Reference::at_rest(Vector3::zeros(), 0.0))
    }

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() <= 1e-5 * (1.0 + b.abs())
    }

    /// x(t) = t³ − t²: value and derivatives against the analytic ones,
    /// and at half speed each derivative of order n divided by 2ⁿ.
    #[test]
    fn a_piece_is_its_polynomial_and_time_scales_its_derivatives() {
        let x = |t: f32| [t * t * t - t * t, 3.0 * t * t - 2.0 * t, 6.0 * t - 2.0, 6.0];
        let m = memory(&[piece([0.0, 0.0, -1.0, 1.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 2.0)]);
        for scale in [1.0f32, 2.0, 0.5] {
            let o = StartOptions {
                time_scale: scale,
                ..AS_PLANNED
            };
            let f = Flight::start(&m, 0, 1_000_000, o, &Reference::at_rest(Vector3::zeros(), 0.0)).unwrap();
            for t in [0.0f32, 0.3, 1.0, 1.7] {
                let s = f.sample(m.bytes(), 1_000_000 + (t * scale * 1e6) as u64);
                let want = x(t);
                let r = &s.reference;
                assert!(
                    close(r.pos_ned_m[0], want[0]),
                    "scale {scale} t {t}: {}",
                    r.pos_ned_m[0]
                );
                assert!(close(r.vel_ned_mps[0], want[1] / scale), "scale {scale} t {t}");
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

    /// The bytes as cflib's `Poly4D.pack` lays them out (x, y, z, yaw
    /// coefficients, then the duration; the Crazyflie's frame) are flown in
    /// NED: north = x, east = −y, down = −z, heading = −yaw.
    #[test]
    fn the_memory_holds_the_crazyflies_frame_and_is_flown_in_ned() {
        let mut raw = Vec::new();
        for (c0, c1) in [(1.0f32, 0.5f32), (2.0, 0.0), (3.0, 0.0), (0.25, 0.1)] {
            let mut c = [0.0f32; 8];
            c[0] = c0;
            c[1] = c1;
            raw.extend(c.iter().flat_map(|v| v.to_le_bytes()));
        }
        raw.extend(2.0f32.to_le_bytes());
        assert_eq!(raw.len(), PIECE_BYTES);
        let mut m = TrajectoryMemory::new();
        m.write(0, &raw).unwrap();
        m.define(3, Definition::new(0, 1).unwrap()).unwrap();
        let f = Flight::start(&m, 3, 0, AS_PLANNED, &Reference::at_rest(Vector3::zeros(), 0.0)).unwrap();
        let r = f.sample(m.bytes(), 1_000_000).reference;
        assert!(close(r.pos_ned_m[0], 1.5) && close(r.vel_ned_mps[0], 0.5));
        assert_eq!((r.pos_ned_m[1], r.pos_ned_m[2]), (-2.0, -3.0));
        assert!(
            close(r.yaw_rad, -0.35) && close(r.yaw_rate_radps, -0.1),
            "{}",
            r.yaw_rad
        );
        assert_eq!(m.read(0, 4).unwrap(), &1.0f32.to_le_bytes());
    }

    /// Each piece runs on its own clock from 0; after the last, the
    /// trajectory rests at its end.
    #[test]
    fn pieces_follow_each_other_and_the_end_is_held() {
        // x = t over 1 s, then x = 1 + 2t over 0.5 s.
        let m = memory(&[
            piece([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 1.0),
            piece([1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 0.5),
        ]);
        let f = start(&m, AS_PLANNED).unwrap();
        let at = |t: f32| f.sample(m.bytes(), (t * 1e6) as u64).reference;
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
        let m = memory(&[piece([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 2.0)]);
        let f = start(
            &m,
            StartOptions {
                reversed: true,
                ..AS_PLANNED
            },
        )
        .unwrap();
        for t in [0.0f32, 0.5, 1.5] {
            let r = f.sample(m.bytes(), (t * 1e6) as u64).reference;
            let u = 2.0 - t;
            assert!(close(r.pos_ned_m[0], u * u), "t {t}: {}", r.pos_ned_m[0]);
            assert!(close(r.vel_ned_mps[0], -2.0 * u), "t {t}: {}", r.vel_ned_mps[0]);
            assert!(close(r.acc_ned_mps2[0], 2.0), "t {t}");
        }
        let end = f.sample(m.bytes(), 3_000_000).reference;
        assert!(close(end.pos_ned_m[0], 0.0) && end.vel_ned_mps[0] == 0.0 && end.acc_ned_mps2[0] == 0.0);
    }

    /// A relative start moves the trajectory to start at the reference; a
    /// relative yaw also turns it about its start, positions and their
    /// derivatives, so that it heads off as the reference heads (a quarter
    /// turn clockwise: north becomes east). The heading is wrapped into
    /// (−π, π].
    #[test]
    fn a_relative_start_moves_and_turns_the_trajectory() {
        // From (5, 0, 0): north at 1 m/s, heading 3 + t rad (past π after 0.14 s).
        let m = memory(&[piece(
            [5.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [3.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            1.0,
        )]);
        let here = Reference::at_rest(Vector3::new(1.0, 2.0, -1.0), 3.0 + FRAC_PI_2);
        let moved = StartOptions {
            relative_position: true,
            ..AS_PLANNED
        };
        let f = Flight::start(&m, 0, 0, moved, &here).unwrap();
        let r = f.sample(m.bytes(), 500_000).reference;
        assert_eq!(r.pos_ned_m, Vector3::new(1.5, 2.0, -1.0));
        assert!(close(r.yaw_rad, 3.5 - 2.0 * PI), "{}", r.yaw_rad);
        assert!(close(r.yaw_rate_radps, 1.0));
        let turned = StartOptions {
            relative_yaw: true,
            ..moved
        };
        let f = Flight::start(&m, 0, 0, turned, &here).unwrap();
        let r = f.sample(m.bytes(), 500_000).reference;
        assert!(
            (r.pos_ned_m - Vector3::new(1.0, 2.5, -1.0)).norm() < 1e-5,
            "{}",
            r.pos_ned_m
        );
        assert!(
            (r.vel_ned_mps - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-5,
            "{}",
            r.vel_ned_mps
        );
        assert!(close(r.yaw_rad, wrap(3.5 + FRAC_PI_2)), "{}", r.yaw_rad);
        // Not relative, the yaw option changes nothing.
        let absolute = StartOptions {
            relative_yaw: true,
            ..AS_PLANNED
        };
        let f = Flight::start(&m, 0, 0, absolute, &here).unwrap();
        assert_eq!(
            f.sample(m.bytes(), 500_000).reference.pos_ned_m,
            Vector3::new(5.5, 0.0, 0.0)
        );
    }

    /// Bad writes, definitions and starts are refused by name, and a
    /// refused write writes nothing.
    #[test]
    fn absurd_pieces_definitions_and_starts_are_refused() {
        let good = piece([0.0; 8], [0.0; 8], 1.0);
        let mut m = memory(&[good, good]);
        let before = m;
        assert_eq!(m.write(4090, &[0; 8]), Err(TrajectoryError::PastTheEnd));
        assert_eq!(m.write(u32::MAX, &[0; 2]), Err(TrajectoryError::PastTheEnd));
        assert_eq!(m, before);
        assert_eq!(m.read(4095, 2), Err(TrajectoryError::PastTheEnd));
        assert_eq!(Definition::new(4096 - 131, 1), Err(TrajectoryError::PastTheEnd));
        assert_eq!(Definition::new(0, 32), Err(TrajectoryError::PastTheEnd));
        assert_eq!(Definition::new(0, 0), Err(TrajectoryError::PastTheEnd));
        assert_eq!(Definition::new(2, 1), Err(TrajectoryError::Alignment));
        assert!(Definition::new(0, MAX_PIECES as u8).is_ok());
        let two = Definition::new(0, 2).unwrap();
        assert_eq!(m.define(10, two), Err(TrajectoryError::Id));
        assert_eq!(
            Flight::start(&m, 1, 0, AS_PLANNED, &Reference::at_rest(Vector3::zeros(), 0.0)),
            Err(TrajectoryError::Undefined)
        );
        // A NaN in piece 1's down polynomial, then an infinite heading.
        let nan_at = (PIECE_BYTES + (2 * COEFFICIENTS + 5) * 4) as u32;
        m.write(nan_at, &f32::NAN.to_le_bytes()).unwrap();
        assert_eq!(start(&m, AS_PLANNED), Err(TrajectoryError::NotFinite { piece: 1 }));
        assert_eq!(m.define(0, two), Err(TrajectoryError::NotFinite { piece: 1 }));
        // A refused definition leaves the id undefined.
        assert_eq!(start(&m, AS_PLANNED), Err(TrajectoryError::Undefined));
        m.write(nan_at, &1.0f32.to_le_bytes()).unwrap();
        // The last piece's last coefficient word, across the bitmap's words.
        let mut full = TrajectoryMemory::new();
        for i in 0..MAX_PIECES {
            full.write((i * PIECE_BYTES) as u32, &good.to_bytes()).unwrap();
        }
        let all = Definition::new(0, MAX_PIECES as u8).unwrap();
        full.define(0, all).unwrap();
        let last = (MAX_PIECES * PIECE_BYTES - 8) as u32;
        full.write(last, &f32::INFINITY.to_le_bytes()).unwrap();
        assert_eq!(full.define(0, all), Err(TrajectoryError::NotFinite { piece: 30 }));
        m.define(0, two).unwrap();
        assert!(start(&m, AS_PLANNED).is_ok());
        for d in [0.0, -1.0, MAX_PIECE_S * 2.0] {
            m.write(PIECE_BYTES as u32 - 4, &f32::to_le_bytes(d)).unwrap();
            assert_eq!(
                start(&m, AS_PLANNED),
                Err(TrajectoryError::Duration { piece: 0 }),
                "{d}"
            );
        }
        m.write(PIECE_BYTES as u32 - 4, &1.0f32.to_le_bytes()).unwrap();
        m.write(PIECE_BYTES as u32, &2000.0f32.to_le_bytes()).unwrap();
        assert_eq!(start(&m, AS_PLANNED), Err(TrajectoryError::Position { piece: 1 }));
        m.write(PIECE_BYTES as u32, &0.0f32.to_le_bytes()).unwrap();
        for s in [0.0, -1.0, f32::NAN, 1e-4, 1e4] {
            let o = StartOptions {
                time_scale: s,
                ..AS_PLANNED
            };
            assert_eq!(start(&m, o), Err(TrajectoryError::TimeScale), "{s}");
        }
        let relative = StartOptions {
            relative_position: true,
            ..AS_PLANNED
        };
        let lost = Reference::at_rest(Vector3::new(0.0, f32::NAN, 0.0), 0.0);
        assert_eq!(Flight::start(&m, 0, 0, relative, &lost), Err(TrajectoryError::Shift));
        // Every refusal says what was wrong.
        assert!(TrajectoryError::Duration { piece: 3 }.to_string().contains("piece 3"));
        assert!(TrajectoryError::PastTheEnd.to_string().contains("4096"));
    }

    /// A flight keeps its definition: the id defined anew changes nothing
    /// flown.
    #[test]
    fn a_flight_keeps_its_definition() {
        let m0 = memory(&[
            piece([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0; 8], 1.0),
            piece([9.0; 8], [0.0; 8], 1.0),
        ]);
        let mut m = m0;
        m.define(0, Definition::new(0, 1).unwrap()).unwrap();
        let f = start(&m, AS_PLANNED).unwrap();
        let before = f.sample(m.bytes(), 3_000_000);
        m.define(0, Definition::new(PIECE_BYTES as u32, 1).unwrap()).unwrap();
        assert_eq!(f.sample(m.bytes(), 3_000_000), before);
        assert!(close(before.reference.pos_ned_m[0], 1.0));
    }
}
