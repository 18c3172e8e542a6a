//! A barometer as a height fix: its altitude (above sea level, drifting
//! with the weather) referenced once to the estimated height, then fused as
//! the change from that reference at most every [`PERIOD_US`]. The MAVLink
//! vehicle's `HIL_SENSOR` barometer and the Crazyflie's BMP388 both go
//! through it.

use crate::schedule::Schedule;
use fc_core::estimate::Fix;

/// A barometric height is fused at most this often, µs (50 Hz).
pub const PERIOD_US: u64 = 20_000;
/// 1σ assumed of a barometric height, m.
pub const SIGMA_M: f32 = 0.1;
/// An altitude outside this range (m above sea level; the BMP388's 300–1250
/// hPa span about −1.9 to +9.2 km) is not a measurement.
pub const ALTITUDE_RANGE_M: (f32, f32) = (-2_000.0, 10_000.0);

/// The standard atmosphere's pressure altitude, m, of a static pressure
/// `pressure_pa` (ISA troposphere: 101 325 Pa at sea level, 288.15 K, lapse
/// 6.5 K/km; h = 44 330.8 · (1 − (p / p₀)^0.190263)). `None` for a pressure
/// that is not positive and finite.
pub fn pressure_altitude_m(pressure_pa: f32) -> Option<f32> {
    if !(pressure_pa.is_finite() && pressure_pa > 0.0) {
        return None;
    }
    Some(44_330.8 * (1.0 - libm::powf(pressure_pa / 101_325.0, 0.190_263)))
}

/// A barometer's reference and rate limit.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Barometer {
    /// The altitude at which the estimated height (up) is 0, m above sea level.
    reference_m: Option<f32>,
    due: Schedule,
}

impl Barometer {
    /// No reference yet.
    pub const fn new() -> Self {
        Self {
            reference_m: None,
            due: Schedule::new(),
        }
    }

    /// Forgets the reference and the schedule (a new session).
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// The reference altitude, m above sea level, once there is one.
    pub fn reference_m(&self) -> Option<f32> {
        self.reference_m
    }

    /// The fix of an altitude `alt_m` (m above sea level) read at `t_us`,
    /// with the estimated height `est_down_m` (NED down, m): `None` before
    /// the estimator has a position (`est_down_m` `None`), when not due, or
    /// when `alt_m` is not finite or outside [`ALTITUDE_RANGE_M`]. Its first
    /// reading is referenced to the estimated height then; every later one
    /// is fused as its change from there (NED down is `reference − alt`).
    pub fn fix(&mut self, t_us: u64, alt_m: f32, est_down_m: Option<f32>) -> Option<Fix> {
        let est_down_m = est_down_m?;
        let (lo, hi) = ALTITUDE_RANGE_M;
        if !(alt_m.is_finite() && (lo..=hi).contains(&alt_m)) {
            return None;
        }
        if !self.due.due(t_us, PERIOD_US) {
            return None;
        }
        let reference = *self.reference_m.get_or_insert(alt_m + est_down_m);
        Some(Fix {
            alt_m: Some(alt_m - reference),
            alt_sigma_m: SIGMA_M,
            ..Fix::EMPTY
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pressure_altitude_follows_the_standard_atmosphere_table() {
        // ICAO standard atmosphere (ISO 2533) table: 101 325 Pa at 0 m,
        // 89 874.6 Pa at 1 000 m, 79 495.2 Pa at 2 000 m, 54 019.9 Pa at
        // 5 000 m, 107 477.7 Pa at −500 m.
        for (p, h) in [
            (101_325.0, 0.0),
            (89_874.6, 1_000.0),
            (79_495.2, 2_000.0),
            (54_019.9, 5_000.0),
            (107_477.7, -500.0),
        ] {
            let got = pressure_altitude_m(p).unwrap();
            assert!((got - h).abs() < 0.5, "{p} Pa: {got} m, the table says {h} m");
        }
        // Near sea level 1 m is 12.0 Pa.
        let dh = pressure_altitude_m(101_313.0).unwrap() - pressure_altitude_m(101_325.0).unwrap();
        assert!((dh - 1.0).abs() < 0.01, "{dh}");
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(pressure_altitude_m(bad), None, "{bad}");
        }
    }

    #[test]
    fn the_first_reading_is_the_reference_and_later_ones_its_change_at_50_hz() {
        let mut b = Barometer::new();
        assert_eq!(b.fix(0, 120.0, None), None, "no estimate, no reference");
        // The estimator has the vehicle 0.5 m up when the first reading (120 m ASL) comes.
        let f = b.fix(1_000, 120.0, Some(-0.5)).unwrap();
        assert_eq!(b.reference_m(), Some(119.5));
        assert_eq!((f.alt_m, f.alt_sigma_m, f.pos_ned_m), (Some(0.5), SIGMA_M, None));
        // 19 ms later: not due; at 20 ms, 1 m higher reads 1.5 m up.
        assert_eq!(b.fix(20_000, 121.0, Some(-0.5)), None);
        assert_eq!(b.fix(21_000, 121.0, Some(-0.5)).unwrap().alt_m, Some(1.5));
        // Not a measurement: refused, and the schedule not spent on it.
        assert_eq!(b.fix(41_000, f32::NAN, Some(0.0)), None);
        assert_eq!(b.fix(41_000, 20_000.0, Some(0.0)), None);
        assert!(b.fix(41_000, 120.0, Some(0.0)).is_some());
        b.reset();
        assert_eq!(b.reference_m(), None);
    }
}
