//! The controller's preview of what the commander will fly. A source that
//! knows its future (a planner segment: a take-off, a landing, a `go_to`, an
//! automatic mode's leg; an uploaded trajectory) is previewed exactly over
//! the controller's horizon ([`crate::commander::Commander::preview_at`]);
//! a stream or a held set-point is extrapolated by the controller itself.
//!
//! Evaluating a whole horizon (20 points of degree-7 polynomials for the
//! fast MPC) in one 1 kHz step costs more than the step's budget has to
//! spare, so [`PreviewFeed`] gives it a point a step for the fast MPC (the
//! horizon's points over [`FILL_US`]; all at once for a slow controller),
//! and once it is complete moves it on a point at a time: each prediction
//! step later, the first point goes and one new last point is evaluated
//! ([`fc_core::control::Controller::roll_preview`]). At every step the
//! controller is told how long ago its preview began
//! ([`fc_core::control::Controller::age_preview`], under a prediction step
//! once it rolls) and moves each point on along its own derivatives by
//! that much. A new source (a new revision) drops the preview of the old
//! one at once; until its own is complete the controller extrapolates.

use fc_core::control::Setpoint;

/// How long filling a preview takes at most, µs: the points a step are
/// the horizon's over this span (at least one, at most all of them).
pub const FILL_US: u64 = 20_000;

/// Preview points held for the controller's next step, taken in index
/// order ([`PreviewSlots::drain`]): slot 0 the new last point of a
/// preview that moves on ([`fc_core::control::Controller::roll_preview`]),
/// slots 1 to [`fc_core::control::regulation::HORIZON`] points of a
/// preview being given ([`fc_core::control::Controller::set_preview`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PreviewSlots {
    points: [Setpoint<f32>; SLOTS],
    /// Bit `k`: slot `k` holds a point.
    held: u32,
}

/// The slots: a roll and one per prediction step of the longest horizon.
pub const SLOTS: usize = fc_core::control::regulation::HORIZON + 1;
const _: () = assert!(SLOTS <= 32, "one bit a slot");

impl Default for PreviewSlots {
    fn default() -> Self {
        Self::new()
    }
}

impl PreviewSlots {
    /// Nothing held.
    pub fn new() -> Self {
        Self {
            points: [Setpoint::hold(nalgebra::Vector3::zeros(), 0.0); SLOTS],
            held: 0,
        }
    }

    /// Holds `sp` in slot `k`; `false` (nothing held) past the last slot.
    pub fn hold(&mut self, k: usize, sp: Setpoint<f32>) -> bool {
        match self.points.get_mut(k) {
            Some(slot) => {
                *slot = sp;
                self.held |= 1 << k;
                true
            }
            None => false,
        }
    }

    /// The points held, in index order, each taken.
    pub fn drain(&mut self) -> impl Iterator<Item = (usize, Setpoint<f32>)> + '_ {
        let held = core::mem::take(&mut self.held);
        let points = &self.points;
        (0..SLOTS)
            .filter(move |k| held & (1 << k) != 0)
            .map(move |k| (k, points[k]))
    }

    /// Drops every point held.
    pub fn clear(&mut self) {
        self.held = 0;
    }

    /// How many points are held.
    pub fn len(&self) -> usize {
        self.held.count_ones() as usize
    }

    /// No point is held.
    pub fn is_empty(&self) -> bool {
        self.held == 0
    }
}

/// Gives a controller its preview (see the module).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PreviewFeed {
    /// The controller's request: points and their spacing, µs.
    request: Option<(usize, u64)>,
    /// Points given each controller step while filling.
    per_step: u8,
    /// The preview being filled: the source's revision, when it began (µs)
    /// and its next point (1-based).
    filling: Option<(u32, u64, usize)>,
    /// The complete preview: the source's revision and when it began, µs.
    in_force: Option<(u32, u64)>,
}

impl PreviewFeed {
    /// No controller that takes a preview.
    pub const fn new() -> Self {
        Self {
            request: None,
            per_step: 0,
            filling: None,
            in_force: None,
        }
    }

    /// A controller was installed that asks for `request` (`(points,
    /// spacing s)`, its [`preview_request`](fc_core::control::Controller::preview_request))
    /// and runs every `period_us`: nothing is in force for it.
    pub fn configure(&mut self, request: Option<(usize, f64)>, period_us: u64) {
        *self = Self::new();
        if let Some((n, h_s)) = request {
            let h_us = libm::round(h_s * 1e6);
            if n > 0 && (1.0..1e9).contains(&h_us) {
                let per = (n as u64 * period_us.max(1)).div_ceil(FILL_US);
                // At most SLOTS points: a byte holds it.
                self.per_step = per.clamp(1, n.min(SLOTS) as u64) as u8;
                self.request = Some((n, h_us as u64));
            }
        }
    }

    /// Drops what is filling and what is in force (the controller was
    /// given another preview, or was reset).
    pub fn drop_preview(&mut self) {
        self.filling = None;
        self.in_force = None;
    }

    /// One controller step at `t_us`, the commander's source at `revision`,
    /// `sample(t)` the source's reference at `t` (`None`: it knows no
    /// future). Filling, the next points go into `slots` by their 1-based
    /// index; complete, a prediction step after it began, it moves on by
    /// one new last point (slot 0). Returns the age to tell the controller
    /// after the slots, s (`None`: nothing complete for this source, and
    /// the controller extrapolates).
    pub fn step(
        &mut self,
        t_us: u64,
        revision: u32,
        slots: &mut PreviewSlots,
        mut sample: impl FnMut(u64) -> Option<Setpoint<f32>>,
    ) -> Option<f32> {
        let (n, h_us) = self.request?;
        if n >= SLOTS {
            return None;
        }
        match self.in_force {
            Some((r, base)) if r == revision && t_us < base.saturating_add(2 * h_us) => {
                let mut base = base;
                if t_us >= base + h_us {
                    // A prediction step on: one new last point.
                    let Some(sp) = sample(base + (n as u64 + 1) * h_us) else {
                        self.drop_preview();
                        return None;
                    };
                    slots.hold(0, sp);
                    base += h_us;
                    self.in_force = Some((r, base));
                }
                return Some(t_us.saturating_sub(base) as f32 * 1e-6);
            }
            // Another source's, or a gap longer than a prediction step: filled anew.
            Some(_) => self.drop_preview(),
            None => {}
        }
        let (mut k, base_us) = match self.filling {
            Some((r, base, k)) if r == revision => (k, base),
            _ => (1, t_us),
        };
        for _ in 0..self.per_step {
            let Some(sp) = sample(base_us.saturating_add(k as u64 * h_us)) else {
                // No future to preview: nothing filling, nothing in force.
                self.drop_preview();
                return None;
            };
            slots.hold(k, sp);
            if k == n {
                self.in_force = Some((revision, base_us));
                self.filling = None;
                return Some(t_us.saturating_sub(base_us) as f32 * 1e-6);
            }
            k += 1;
        }
        self.filling = Some((revision, base_us, k));
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn at(t_us: u64) -> Option<Setpoint<f32>> {
        Some(Setpoint::hold(Vector3::new(t_us as f32 * 1e-6, 0.0, -1.0), 0.0))
    }

    fn x(sp: Option<Setpoint<f32>>) -> f32 {
        sp.unwrap().pos_ned_m[0]
    }

    #[test]
    fn the_fast_mpcs_preview_fills_a_point_a_step_then_rolls_a_point_a_prediction_step() {
        let mut f = PreviewFeed::new();
        f.configure(Some((20, 0.05)), 1000);
        let mut slots = PreviewSlots::new();
        // Twenty steps of 1 ms: a point each, from the first step's time.
        for s in 0..20u64 {
            let age = f.step(1_000_000 + s * 1000, 7, &mut slots, at);
            let got: Vec<_> = slots.drain().collect();
            let k = s as usize + 1;
            assert_eq!(got.len(), 1, "step {s}");
            assert_eq!(got[0].0, k);
            assert!(
                (got[0].1.pos_ned_m[0] - (1.0 + 0.05 * k as f32)).abs() < 1e-6,
                "point {k}"
            );
            if s < 19 {
                assert_eq!(age, None);
            } else {
                // Complete: began 19 ms ago.
                assert!((age.unwrap() - 0.019).abs() < 1e-7);
            }
        }
        // It ages, untouched, until a prediction step after it began...
        let age = f.step(1_049_000, 7, &mut slots, at);
        assert!(slots.is_empty() && (age.unwrap() - 0.049).abs() < 1e-7);
        // ... then moves on: the point at 1 s + 21 steps is its new last.
        let age = f.step(1_050_000, 7, &mut slots, at);
        assert_eq!(slots.len(), 1);
        let (k, roll) = slots.drain().next().unwrap();
        assert!(k == 0 && (x(Some(roll)) - 2.05).abs() < 1e-6);
        assert_eq!(age, Some(0.0));
        let age = f.step(1_103_000, 7, &mut slots, at);
        assert!((x(slots.drain().next().map(|(_, p)| p)) - 2.10).abs() < 1e-6);
        assert!((age.unwrap() - 0.003).abs() < 1e-7);
        // A gap of two prediction steps: filled anew, from now.
        assert_eq!(f.step(1_300_000, 7, &mut slots, at), None);
        let (k, p) = slots.drain().next().unwrap();
        assert!(k == 1 && (p.pos_ned_m[0] - 1.35).abs() < 1e-6);
        // A new source drops it at once; one without a future drops all.
        assert_eq!(f.step(1_301_000, 8, &mut PreviewSlots::new(), at), None);
        assert_eq!(f.step(1_302_000, 8, &mut PreviewSlots::new(), |_| None), None);
        assert_eq!(f, {
            let mut g = PreviewFeed::new();
            g.configure(Some((20, 0.05)), 1000);
            g
        });
    }

    #[test]
    fn slots_hold_what_fits_and_give_it_once_in_order() {
        let mut s = PreviewSlots::new();
        assert!(s.hold(5, at(5).unwrap()) && s.hold(0, at(0).unwrap()) && s.hold(SLOTS - 1, at(9).unwrap()));
        assert!(!s.hold(SLOTS, at(1).unwrap()));
        let ks: Vec<usize> = s.drain().map(|(k, _)| k).collect();
        assert_eq!(ks, [0, 5, SLOTS - 1]);
        assert!(s.is_empty() && s.drain().next().is_none());
    }

    #[test]
    fn a_slow_controller_gets_its_whole_preview_at_once_and_absurd_requests_none() {
        let mut f = PreviewFeed::new();
        f.configure(Some((20, 0.25)), 250_000);
        let mut slots = PreviewSlots::new();
        assert_eq!(f.step(0, 1, &mut slots, at), Some(0.0));
        assert_eq!(slots.len(), 20);
        // No controller that takes one, or one asking for more than the
        // slots hold, or an absurd spacing: nothing given.
        for req in [None, Some((21, 0.05)), Some((20, 0.0)), Some((20, f64::NAN))] {
            let mut g = PreviewFeed::new();
            g.configure(req, 1000);
            let mut s = PreviewSlots::new();
            assert_eq!(g.step(0, 1, &mut s, at), None);
            assert!(s.is_empty());
        }
    }
}
