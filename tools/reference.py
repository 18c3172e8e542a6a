"""The references every rotorpy flight is measured against, for our flight
controller and for a peer alike: a step between waypoints, and the `circle`
and `eight` scenarios of `sil-host` (docs/book/src/model.md §9, starting
1 m above home), NED about home, as flat outputs (position and its first
four derivatives). `tools/rotorpy_hil.py` checks them against the
set-points our flight controller flew (its trace), so both fly one path.

The flight windows (`windows`) are the peer table's: the whole span and its
steady part, per kind of flight.
"""
import math

import numpy as np

# The scenarios' numbers (sil-host/src/scenario.rs, Scenario::default_for).
START_NED_M = np.array([0.0, 0.0, -1.0])
CIRCLE_R_M, CIRCLE_PERIOD_S = 2.0, 20.0
EIGHT_A_M, EIGHT_PERIOD_S = 1.0, 6.0


def scenario_at(kind, tau):
    """`kind`'s reference `tau` s after it starts: position and its first
    four derivatives (NED, m, m/s, ...), as five arrays."""
    if kind == "circle":
        r, w = CIRCLE_R_M, 2 * math.pi / CIRCLE_PERIOD_S
        s, c = math.sin(w * tau), math.cos(w * tau)
        return (START_NED_M + [r * s, r * (1 - c), 0.0], np.array([r * w * c, r * w * s, 0.0]),
                np.array([-r * w**2 * s, r * w**2 * c, 0.0]), np.array([-r * w**3 * c, -r * w**3 * s, 0.0]),
                np.array([r * w**4 * s, -r * w**4 * c, 0.0]))
    if kind == "eight":
        a, w = EIGHT_A_M, 2 * math.pi / EIGHT_PERIOD_S
        s1, c1 = math.sin(w * tau), math.cos(w * tau)
        s2, c2 = math.sin(2 * w * tau), math.cos(2 * w * tau)
        return (START_NED_M + [a * s1, 0.5 * a * s2, 0.0], np.array([a * w * c1, a * w * c2, 0.0]),
                np.array([-a * w**2 * s1, -2 * a * w**2 * s2, 0.0]),
                np.array([-a * w**3 * c1, -4 * a * w**3 * c2, 0.0]),
                np.array([a * w**4 * s1, 8 * a * w**4 * s2, 0.0]))
    raise ValueError(f"no reference for scenario {kind!r}: circle or eight")


class Reference:
    """What a flight follows at `t` s after its first step: the waypoints'
    last reached position (`waypoints`: (t, n, e, d) tuples), the scenario
    `kind` from `start_s` (its start point held before), or an uploaded
    trajectory's `pieces` (`fctools.pieces.Pieces`, from its hover at
    START_NED_M) from `start_s`."""

    def __init__(self, waypoints=None, kind=None, start_s=3.0, pieces=None):
        self.waypoints, self.kind, self.start_s, self.pieces = waypoints, kind, start_s, pieces

    def yaw_enu(self, t):
        """The heading flown at `t` as rotorpy's yaw (ENU: 0 east,
        counter-clockwise) and its rate: a trajectory's own heading, which
        starts north; otherwise east (rotorpy's start), held."""
        if self.pieces is None:
            return 0.0, 0.0
        psi, rate = self.pieces.heading(max(t - self.start_s, 0.0))
        return math.pi / 2 - psi, (-rate if t >= self.start_s else 0.0)

    def at(self, t):
        if self.pieces is not None:
            flat = self.pieces.at(max(t - self.start_s, 0.0))
            if t < self.start_s:
                zero = np.zeros(3)
                return flat[0], zero, zero, zero, zero
            return flat
        if self.waypoints:
            w = [p for p in self.waypoints if p[0] <= t] or self.waypoints[:1]
            zero = np.zeros(3)
            return np.array(w[-1][1:4], dtype=float), zero, zero, zero, zero
        flat = scenario_at(self.kind, max(t - self.start_s, 0.0))
        if t < self.start_s:
            zero = np.zeros(3)
            return flat[0], zero, zero, zero, zero
        return flat

    def windows(self, end_s):
        """The spans a flight is measured over, (name, from, to) in s: the
        whole (from the step, or the scenario's start) and the steady part
        (a step: 5 s after it; the circle: 5 s after its start; the eight:
        after its first lap; a trajectory: the whole of it, and the hold at
        its end after it)."""
        if self.pieces is not None:
            # A trajectory: the whole of it, then the hold at its end.
            t_end = self.start_s + self.pieces.duration_s
            return [("whole", self.start_s, t_end), ("steady", t_end, end_s)]
        if self.waypoints:
            t_step = self.waypoints[-1][0]
            return [("whole", t_step, end_s), ("steady", t_step + 5.0, end_s)]
        settle = EIGHT_PERIOD_S if self.kind == "eight" else 5.0
        return [("whole", self.start_s, end_s), ("steady", self.start_s + settle, end_s)]


def window_figures(ref, track, commands, hover_frac, end_s, rotors):
    """The peer table's figures of one flight, per window: RMSE, worst and
    final 3-D distance to the reference (m), the motor effort (RMS of the
    commanded rotor speeds' departure from hover, as fractions of the
    maximum, over the four rotors) and the peak rotor speed (the fastest
    of the four true rotor speeds, fraction of the maximum: 1 is
    saturated). `track` rows: t, north, east, down (rotorpy's truth at each
    step); `commands`: the rotor speeds commanded at each step, fractions
    of the maximum; `rotors`: rotorpy's true rotor speeds at each step,
    fractions of the maximum. A step adds its settling time: from the step
    until the distance stays within 2 cm (2 % of its 1 m)."""
    t = track[:, 0]
    ref_pos = np.array([ref.at(ti)[0] for ti in t])
    dist = np.linalg.norm(track[:, 1:4] - ref_pos, axis=1)
    out = {}
    for name, t0, t1 in ref.windows(end_s):
        w = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
        if not w.any():
            continue
        eff = commands[w] - hover_frac
        out[name] = {
            "window_s": [t0, t1],
            "rmse_m": float(np.sqrt(np.mean(dist[w] ** 2))),
            "worst_m": float(dist[w].max()),
            "final_m": float(dist[w][-1]),
            "effort": float(np.sqrt(np.mean(eff**2))),
            "peak_rotor": float(rotors[w].max()),
        }
    if ref.waypoints:
        t_step = ref.waypoints[-1][0]
        after = t >= t_step
        outside = np.nonzero(after & (dist > 0.02))[0]
        settled = None
        if len(outside) == 0:
            settled = 0.0
        elif outside[-1] + 1 < len(t):
            settled = float(t[outside[-1] + 1] - t_step)
        out["settling_s"] = settled
    return out
