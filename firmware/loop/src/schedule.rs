//! When a periodic task runs on a stream of faster steps: the controller
//! (every 2 or 5 ms) under the IMU and estimator (every 1 ms), as a real
//! flight controller runs its rate-limited tasks under the gyro's interrupt.
//!
//! The task runs at the first step and then at the first step at or after
//! each point of the grid `t₀ + k·period` (µs). The grid is fixed by the
//! first step: a late or missing step delays one run, it does not shift
//! the later ones, and grid points passed without any step are skipped,
//! not run in a burst. Everything is integer µs, so two ends that see the
//! same step times (the host's flight loop and the flight controller over
//! the wire) run the task at the same steps.

/// A periodic task's next due time on its grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Schedule {
    /// The next grid point, µs (`None`: the next step is the first).
    next_us: Option<u64>,
}

impl Schedule {
    /// A schedule whose grid starts at the next step.
    pub const fn new() -> Self {
        Self { next_us: None }
    }

    /// Whether the task runs at the step at `now_us` (µs, increasing), with
    /// `period_us` between grid points (0 is taken as 1: every step).
    pub fn due(&mut self, now_us: u64, period_us: u64) -> bool {
        let period = period_us.max(1);
        match self.next_us {
            None => {
                self.next_us = Some(now_us.saturating_add(period));
                true
            }
            Some(next) if now_us >= next => {
                // The first grid point after `now_us` (skipping missed ones).
                let missed = (now_us - next) / period;
                self.next_us = Some(next.saturating_add((missed + 1).saturating_mul(period)));
                true
            }
            Some(_) => false,
        }
    }

    /// Forgets the grid: the next step runs the task and starts a new one.
    pub fn reset(&mut self) {
        self.next_us = None;
    }
}

/// A period in seconds as whole µs (rounded: `0.01_f32` is 9 999.999… µs).
pub fn period_us(period_s: f64) -> u64 {
    if period_s.is_finite() && period_s > 0.0 {
        (period_s * 1e6 + 0.5) as u64
    } else {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn runs(times: &[u64], period: u64) -> heapless::Vec<u64, 32> {
        let mut s = Schedule::new();
        times.iter().copied().filter(|&t| s.due(t, period)).collect()
    }

    #[test]
    fn a_five_millisecond_task_under_a_one_millisecond_step_runs_every_fifth() {
        let times: heapless::Vec<u64, 32> = (0..21u64).map(|k| 1_000 * k).collect();
        assert_eq!(runs(&times, 5_000).as_slice(), &[0, 5_000, 10_000, 15_000, 20_000]);
        // A grid that starts late stays on its own phase.
        assert_eq!(runs(&times[3..], 5_000).as_slice(), &[3_000, 8_000, 13_000, 18_000]);
    }

    #[test]
    fn a_missing_step_delays_one_run_and_the_grid_holds() {
        // The step at 5 ms is lost: the task runs at 6 ms, then at 10 ms again.
        let times = [
            0, 1_000, 2_000, 3_000, 4_000, 6_000, 7_000, 8_000, 9_000, 10_000, 11_000,
        ];
        assert_eq!(runs(&times, 5_000).as_slice(), &[0, 6_000, 10_000]);
        // A long gap runs once when it ends, not once per missed point.
        assert_eq!(
            runs(&[0, 1_000, 23_000, 24_000, 25_000], 5_000).as_slice(),
            &[0, 23_000, 25_000]
        );
    }

    #[test]
    fn a_zero_period_runs_every_step_and_reset_restarts_the_grid() {
        assert_eq!(runs(&[0, 1, 2], 0).as_slice(), &[0, 1, 2]);
        let mut s = Schedule::new();
        assert!(s.due(0, 5_000));
        assert!(!s.due(2_000, 5_000));
        s.reset();
        assert!(s.due(2_000, 5_000));
        assert!(!s.due(5_000, 5_000));
        assert!(s.due(7_000, 5_000));
    }

    #[test]
    fn periods_round_to_the_nearest_microsecond() {
        assert_eq!(period_us(f64::from(0.01_f32)), 10_000);
        assert_eq!(period_us(0.005), 5_000);
        assert_eq!(period_us(f64::NAN), 0);
        assert_eq!(period_us(-1.0), 0);
    }
}
