#!/usr/bin/env python3
"""MAVSDK's `Failure` plugin (PyPI `mavsdk` 4.x, unmodified) injects PX4's
sensor faults into the flight controller while it flies rotorpy, as a PX4
user tests failsafes in simulation. Run by tools/rotorpy_hil.py
--mavsdk-failure against `sil-host px4-hil --gcs`; every figure is taken
from rotorpy's truth (--truth-port: north, east, down about the start, m).

1. connect, as tools/mavsdk_flight.py does; injection off
   (`SYS_FAILURE_EN` 0): `Failure.inject` is denied; set to 1 (the
   vehicle's parameters are REAL32: `set_param_float`); a fault not
   modelled (a wrong gyro) is unsupported; the accelerometer stuck on the
   ground refuses an arming by name, then is cleared;
2. arm, take off to 1.5 m, Hold;
3. each fault the vehicle should fly through, injected for a few simulated
   seconds in Hold and then cleared (`FailureType.OK`): the vehicle stays in
   Hold, and rotorpy's worst distance from where it held is measured;
4. a fault it must not fly on (the position fix wrong by metres, or stuck;
   the accelerometer stuck; the gyro off): the vehicle says which sensor
   and why, lands where it is (without the accelerometer, on the specific
   force its commanded thrust gives) and disarms, or without the gyro
   stops its motors and falls; the landing's distance from where it held
   is measured.
   Then the fault is cleared, it arms again for the next.

Prints `fault check: P passed, F failed`; `--table FILE` writes each fault's
row (JSON): what was injected, what the vehicle said and did, the worst
distance from where it held, how long it took. `--only` flies some of the
faults;
`--tag` names their figures (`fault_…` by default).
"""
import argparse
import asyncio
import json
import math
import sys
import time

from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.failure import FailureAsync, FailureError, FailureType, FailureUnit
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync
from mavsdk.plugins.failure import FailureResult

from fctools.checks import Checks
from fctools.truth import Truth
from mavsdk_flight import Flight
from measure import record

SOURCE = "tools/rotorpy_hil.py --mavsdk-failure"

# What the vehicle flies through (fault, seconds injected, the bound on the
# truth's worst distance from where it held, m) and what it lands on.
FLY_THROUGH = [
    (FailureUnit.SENSOR_GPS, FailureType.INTERMITTENT, 4.0, 0.05),
    (FailureUnit.SENSOR_GPS, FailureType.OFF, 1.5, 0.10),
]
# and what it must say, in order (a landing ends "landed: disarmed"; without
# the gyro the motors stop: a quadrotor cannot fly without its rates).
NO_POSITION = "no position: landing"
NO_IMU = "IMU lost: landing"
LANDED = "landed: disarmed"
GROUND_STUCK = "arming refused: accelerometer stuck (20 the same)"
LAND_ON = [
    (FailureUnit.SENSOR_GPS, FailureType.WRONG, ["position fix wrong (10 in a row): not used", NO_POSITION, LANDED]),
    (FailureUnit.SENSOR_GPS, FailureType.STUCK, ["position fix stuck (20 the same): not used", NO_POSITION, LANDED]),
    (FailureUnit.SENSOR_ACCEL, FailureType.STUCK, ["accelerometer stuck (20 the same): not used", NO_IMU, LANDED]),
    (FailureUnit.SENSOR_GYRO, FailureType.OFF, [NO_IMU, "no gyro: motors off"]),
]


def name(unit, kind):
    return f"{unit.name.lower().replace('sensor_', '')} {kind.name.lower()}"


def key(unit, kind):
    """A fault's name as its figures and `--only` spell it: `gps_stuck`."""
    return name(unit, kind).replace(" ", "_")


class Faults(Flight):
    def __init__(self, truth, timeout, only=None, tag="fault"):
        super().__init__(truth, timeout)
        self.check = Checks("fault", flush=True)
        self.fly_through = [f for f in FLY_THROUGH if only is None or key(*f[:2]) in only]
        self.land_on = [f for f in LAND_ON if only is None or key(*f[:2]) in only]
        self.tag = tag
        self.texts = []  # (simulated s, text)
        self.rows = []

    async def sim_sleep(self, secs):
        """Waits `secs` of simulated time (rotorpy's)."""
        self.truth.poll()
        t0 = self.truth.t
        end = time.time() + 50 * secs + self.timeout
        while self.truth.t < t0 + secs and time.time() < end:
            await asyncio.sleep(0.02)
            self.truth.poll()

    def worst_from(self, ned, since_t, horizontal=False):
        """The truth's worst distance from `ned` (`horizontal`: north and
        east only) since simulated `since_t`, m."""
        self.truth.poll()
        k = 2 if horizontal else 3
        return max((math.dist(p[:k], ned[:k]) for t, p in self.truth.tracks.get(0, []) if t >= since_t),
                   default=math.inf)

    def said_since(self, t0):
        return [s for t, s in self.texts if t >= t0]

    async def inject(self, failure, unit, kind, expect=FailureResult.SUCCESS):
        try:
            await failure.inject(unit, kind, 0)
            result = FailureResult.SUCCESS
        except FailureError as e:
            result = e.result
        return self.check(result == expect, f"inject {name(unit, kind)}: {result.name} (expected {expect.name})")

    async def stuck_on_the_ground(self, failure, action, tel):
        """The accelerometer stuck before take-off: the arming is refused by
        name (rotorpy's IMU reads with noise, so 20 readings the same are a
        stuck part); cleared, the flight goes on."""
        await self.inject(failure, FailureUnit.SENSOR_ACCEL, FailureType.STUCK)
        await self.sim_sleep(0.2)
        self.truth.poll()
        t0 = self.truth.t
        try:
            await action.arm()
            refused = None
        except Exception as e:  # noqa: BLE001 -- MAVSDK's ActionError: its result is in its text
            refused = str(e).split(";")[0]
        await self.sim_sleep(0.2)
        said = self.said_since(t0)
        self.check(refused is not None and not await tel.armed() and GROUND_STUCK in said,
                   f"accel stuck on the ground: the arming refused ({refused}), said {said}")
        await self.inject(failure, FailureUnit.SENSOR_ACCEL, FailureType.OK)
        await self.sim_sleep(0.2)

    async def take_off(self, action, tel):
        async def mode_is(m):
            return await tel.flight_mode() == m

        self.truth.poll()
        n, e, _ = self.truth.pos
        await action.arm()
        await self.until(tel.armed, "armed")
        await action.takeoff()
        await self.until(lambda: mode_is(FlightMode.HOLD), "takeoff, then Hold")
        hold = [n, e, -1.5]
        await self.settle_at(hold, 0.05, 1.0, f"rotorpy within 5 cm of 1.5 m above ({n:.2f}, {e:.2f}) (1 s)")
        return hold

    async def fly(self, system):
        """Flies `system` (see the module's documentation)."""
        tel, action = TelemetryAsync(system), ActionAsync(system)
        param, failure = ParamAsync(system), FailureAsync(system)

        async def listen():
            async for s in tel.subscribe_status_text():
                self.truth.poll()
                self.texts.append((self.truth.t or 0.0, s.text))
                print(f"     [{self.truth.t or 0.0:7.2f} s] {s.text}", flush=True)

        listener = asyncio.create_task(listen())
        await self.pace(system, param)

        async def healthy():
            h = await tel.health()
            return h.is_local_position_ok and h.is_home_position_ok and h.is_armable

        await self.until(healthy, "health: local position, home, armable")
        await self.inject(failure, FailureUnit.SENSOR_GPS, FailureType.OFF, FailureResult.DENIED)
        await param.set_param_float("SYS_FAILURE_EN", 1.0)
        self.check(await param.get_param_float("SYS_FAILURE_EN") == 1.0, "SYS_FAILURE_EN set to 1")
        await self.inject(failure, FailureUnit.SENSOR_GYRO, FailureType.WRONG, FailureResult.UNSUPPORTED)
        await self.stuck_on_the_ground(failure, action, tel)
        await action.set_takeoff_altitude(1.5)
        hold = await self.take_off(action, tel)

        for unit, kind, secs, bound in self.fly_through:
            self.truth.poll()
            t0 = self.truth.t
            await self.inject(failure, unit, kind)
            await self.sim_sleep(secs)
            await self.inject(failure, unit, FailureType.OK)
            await self.sim_sleep(1.0)
            worst = self.worst_from(hold, t0)
            mode = await tel.flight_mode()
            said = self.said_since(t0)
            self.check(mode == FlightMode.HOLD and worst <= bound,
                       f"{name(unit, kind)} for {secs} s: still {mode.name}, rotorpy at most "
                       f"{100 * worst:.1f} cm from where it held ({100 * bound:.0f} cm); said {said}")
            self.rows.append({"fault": name(unit, kind), "injected_s": secs, "did": f"flew on in {mode.name}",
                              "said": said, "worst_m": worst, "landed": False})
            record(f"{self.tag}_{key(unit, kind)}_worst_m", worst, "m", SOURCE)
            await self.settle_at(hold, 0.05, 0.5, "back within 5 cm of where it held")

        for k, (unit, kind, texts) in enumerate(self.land_on):
            self.truth.poll()
            t0 = self.truth.t
            await self.inject(failure, unit, kind)

            async def down():
                return await tel.landed_state() == LandedState.ON_GROUND and not await tel.armed()

            ok = await self.until(down, f"{name(unit, kind)}: landed and disarmed", timeout=3 * self.timeout)
            # Motors stopped in the air, it falls: up to 2 s to the ground.
            for _ in range(20):
                self.truth.poll()
                if abs(self.truth.pos[2]) < 0.05:
                    break
                await self.sim_sleep(0.1)
            self.truth.poll()
            said = self.said_since(t0)
            heard = [t for t in said if t in texts]
            self.check(heard[:len(texts)] == texts,
                       f"{name(unit, kind)}: said which sensor and why, and landed: {said}")
            landed_at = list(self.truth.pos)
            off = math.dist(landed_at[:2], hold[:2])
            self.check(ok and off <= 0.5 and abs(landed_at[2]) < 0.05,
                       f"{name(unit, kind)}: on the ground {100 * off:.1f} cm from where it held (50 cm), "
                       f"{self.truth.t - t0:.1f} s after the fault")
            drift = self.worst_from(hold, t0, horizontal=True)
            self.rows.append({"fault": name(unit, kind), "injected_s": None, "did": "landed and disarmed",
                              "said": said, "worst_m": drift, "landed_off_m": off,
                              "landed_after_s": self.truth.t - t0, "landed": ok})
            fig = f"{self.tag}_{key(unit, kind)}"
            if ok:
                record(f"{fig}_drift_m", drift, "m", SOURCE)
                record(f"{fig}_landed_off_m", off, "m", SOURCE)
                record(f"{fig}_landed_after_s", self.truth.t - t0, "s", SOURCE)
            await self.inject(failure, unit, FailureType.OK)
            if k + 1 < len(self.land_on):
                await self.sim_sleep(1.0)
                hold = await self.take_off(action, tel)
        listener.cancel()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin://127.0.0.1:14550")
    ap.add_argument("--truth-port", type=int, default=14560)
    ap.add_argument("--timeout", type=float, default=60.0, help="wall seconds per step")
    ap.add_argument("--table", help="write the faults' rows here (JSON)")
    every = [key(*f[:2]) for f in FLY_THROUGH + LAND_ON]
    ap.add_argument("--only", metavar="FAULT,...", help=f"fly these faults only (of {', '.join(every)})")
    ap.add_argument("--tag", default="fault", help="the figures' prefix (TAG_gps_stuck_landed_off_m)")
    a = ap.parse_args()
    only = None
    if a.only:
        only = set(a.only.split(","))
        if not only <= set(every):
            ap.error(f"--only: no fault {', '.join(sorted(only - set(every)))} (of {', '.join(every)})")
    truth = Truth(a.truth_port)
    f = Faults(truth, a.timeout, only, a.tag)
    try:
        asyncio.run(f.run(a.url))
    except Exception as e:  # noqa: BLE001 -- a MAVSDK error is a failed check, with its reason
        f.check(False, f"MAVSDK raised {type(e).__name__}: {e}")
    if a.table:
        with open(a.table, "w") as out:
            json.dump(f.rows, out, indent=2)
    print(f.check.summary(say_failures=True), flush=True)
    return f.check.exit_code()


if __name__ == "__main__":
    sys.exit(main())
