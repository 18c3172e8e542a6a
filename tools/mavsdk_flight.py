#!/usr/bin/env python3
"""MAVSDK (PyPI `mavsdk` 4.x, the native binding of MAVSDK's C++ library),
unmodified, flies the flight controller as it flies PX4, using only
MAVSDK's public API. Run by tools/rotorpy_hil.py --mavsdk against
`sil-host px4-hil --gcs` flying rotorpy; every step is checked against
rotorpy's truth, which rotorpy_hil.py sends to --truth-port (north, east,
down about the start, m, with the simulated time).

1. connect (`udpin://`, as to a PX4 SITL); the autopilot is PX4; when
   the simulation runs more than 3x slower than real time (the image in
   QEMU), the vehicle's heartbeat rate and its ground-station timeouts are
   fitted to it (`Flight.pace`);
2. telemetry: health (local and global position, home, armable), home,
   position, attitude, no battery (none is measured), flight mode, landed state, armed;
3. param get and set; `action.set_takeoff_altitude(1.5)` (PX4's
   MIS_TAKEOFF_ALT);
4. `action.arm()`, `action.takeoff()`: Hold at 1.5 m (5 cm, rotorpy);
5. joystick: `manual_control` input streamed at 20 Hz,
   `start_position_control()` (Position), the stick forward: rotorpy moves
   0.8 m along its heading (rotorpy's vehicle faces east), holding its
   track and height;
5. offboard: a set-point where it is, `start()`, a 2 m move north, `stop()`
   (Hold): within 5 cm of the set-point;
6. mission: four waypoints uploaded (and downloaded back), started, its
   progress to the end; rotorpy passes within 5 cm of each;
7. `action.return_to_launch()`: landed and disarmed within 20 cm of home.

Prints `mavsdk check: P passed, F failed` (and what failed); exits non-zero
if anything failed.
"""
import argparse
import asyncio
import json
import math
import sys
import time

from mavsdk import Autopilot
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.manual_control import ManualControlAsync
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync
from mavsdk.plugins.mavlink_direct import MavlinkMessage

from fctools.checks import Checks
from fctools.params import table_length
from fctools.truth import Truth
from measure import record


class Flight:
    def __init__(self, truth, timeout, lossy=False):
        self.truth = truth
        self.timeout = timeout
        # The link loses datagrams (--lossy): the vehicle's heartbeat is
        # asked for every 0.5 s of wall time whatever the pace (`pace`).
        self.lossy = lossy
        self.check = Checks("mavsdk", flush=True)
        # Each transfer (a parameter set and read back, a mission up and
        # back): completed exactly, failed (MAVSDK raised), or corrupted
        # (completed, and not what was sent).
        self.transfers = {"completed": 0, "failed": 0, "corrupted": 0}

    def transfer(self, exact):
        """Counts one transfer that completed: exactly, or corrupted."""
        self.transfers["completed" if exact else "corrupted"] += 1
        return exact

    async def again(self, make, what, tries=5):
        """`await make()`, made again when MAVSDK gives up on it (its own
        retries timed out: a clean failure, counted), up to `tries` times
        (at 30 % lost each way MAVSDK gives up on one download in three),
        as a ground station does over a lossy link; the last failure is
        raised. A transfer MAVSDK refuses as BUSY (the one it gave up on is
        still winding down its own retries: nothing was transferred) is
        made again too, after a second, and counted as failed."""
        async def failed():
            self.transfers["failed"] += 1
            return False

        return await self.retry(make, what, tries, failed, busy_wait_s=1.0)

    async def command(self, make, what, done):
        """`await make()`, a command, made again when MAVSDK gives up on it
        (no COMMAND_ACK within its retries: a clean failure) unless
        `await done()` says the vehicle did it (the command heard, its
        acknowledgement lost), up to five times, as a ground station does
        over a lossy link; the last failure is raised."""
        return await self.retry(make, what, 5, done)

    async def retry(self, make, what, tries, timed_out, busy_wait_s=None):
        """`await make()` up to `tries` times while MAVSDK's error is a
        TIMEOUT (or, with `busy_wait_s`, a BUSY, made again after that many
        wall seconds); after each, `await timed_out()` says whether it is
        done after all (then None is returned). Any other error, or the
        last one, is raised."""
        for k in range(tries):
            try:
                return await make()
            except Exception as e:  # MAVSDK's errors share no base class, only their text
                busy = busy_wait_s is not None and "BUSY" in str(e).split(";")[0]
                if k + 1 == tries or not ("TIMEOUT" in str(e) or busy):
                    raise
                why = f"     {what}: {type(e).__name__} {str(e).split(';')[0]}"
                if await timed_out():
                    print(f"{why}, but done", flush=True)
                    return None
                print(f"{why}: made again", flush=True)
                if busy:
                    await asyncio.sleep(busy_wait_s)

    async def until(self, cond, what, timeout=None):
        """Waits (wall time) until `cond()` holds; checks it."""
        end = time.time() + (timeout or self.timeout)
        while time.time() < end:
            # Keeps the truth current (its datagrams are not left to queue).
            self.truth.poll()
            if await cond():
                return self.check(True, what)
            await asyncio.sleep(0.05)
        return self.check(False, what + " (timed out)")

    async def settle_at(self, ned, tol, hold_s, what):
        """rotorpy within `tol` m of `ned` for `hold_s` simulated seconds."""
        since = None

        async def near():
            nonlocal since
            d = self.truth.dist(ned)
            if d > tol:
                since = None
                return False
            since = self.truth.t if since is None else since
            return self.truth.t - since >= hold_s

        ok = await self.until(near, what)
        if not ok:
            print(f"     rotorpy at {self.truth.pos}, {self.truth.dist(ned):.3f} m from {ned}", flush=True)
        return ok

    async def pace(self, system, param):
        """Fits the vehicle's clocks to a simulation slower than real time
        (the image in QEMU runs about 5x slower). MAVSDK paces itself by
        the wall clock: it drops a system whose heartbeat is silent for 3 s
        and sends its own heartbeat at 1 Hz, its joystick input and offboard
        set-points at 20 Hz. The vehicle keeps simulated time. So, through
        MAVSDK's public API, when a simulated second takes more than three of
        wall time, or over a link that loses datagrams (`--lossy`) at any
        pace: the vehicle's heartbeat is asked for every 0.5 s of wall
        time (MAV_CMD_SET_MESSAGE_INTERVAL, through mavlink_direct), and the
        timeouts on the ground station's streams (FS_GCS_MS, COM_RC_LOSS_T,
        COM_OF_LOSS_T) are lengthened by the slowdown."""
        slow = await self.truth.slowdown()
        print(f"     {slow:.1f} wall seconds per simulated second", flush=True)
        if slow <= 3.0 and not self.lossy:
            return
        # A link that loses datagrams, slower than real time: two heartbeats
        # lost in a row (one in ten at 30 %) are MAVSDK's 3 s of silence.
        slow = max(slow, 1.0)
        direct = MavlinkDirectAsync(system)

        async def never():
            return False

        ack = await self.command(lambda: direct.send_command(MavlinkMessage(
            message_name="COMMAND_LONG", target_system_id=1, target_component_id=1,
            fields_json=json.dumps({"target_system": 1, "target_component": 1, "command": 511,
                                    "confirmation": 0, "param1": 0, "param2": 0.5e6 / slow, "param3": 0,
                                    "param4": 0, "param5": 0, "param6": 0, "param7": 0}))),
                                 "the heartbeat's interval", never)
        self.check(json.loads(ack.fields_json).get("result") == 0,
                   f"heartbeat every {0.5 / slow:.3f} simulated s (SET_MESSAGE_INTERVAL): {ack.fields_json}")
        # The vehicle's own values, scaled: FS_GCS_MS takes whole
        # milliseconds, the others tenths of a second.
        # Each within the range the vehicle takes (refused beyond it): a
        # machine 12x slower than real time would ask for more than a
        # minute of FS_GCS_MS.
        for name, digits, most in (("FS_GCS_MS", 0, 60000.0), ("COM_RC_LOSS_T", 1, 60.0), ("COM_OF_LOSS_T", 1, 60.0)):
            value = min(float(round(await self.again(lambda n=name: param.get_param_float(n), name) * slow,
                                    digits)), most)
            await self.again(lambda n=name, v=value: param.set_param_float(n, v), name)
            got = await self.again(lambda n=name: param.get_param_float(n), name)
            self.check(self.transfer(abs(got - value) < 1e-3),
                       f"{name} lengthened to {value}")

    async def run(self, url):
        """Connects to the first autopilot on `url` (checked) as a ground
        station and flies it (`fly`)."""
        cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(cfg) as mavsdk:
            await mavsdk.add_any_connection(url)
            system = await mavsdk.first_autopilot(timeout_s=self.timeout)
            if self.check(system is not None, "an autopilot connects"):
                await self.fly(system)

    async def fly(self, system):
        """Flies `system` (see the module's documentation)."""
        self.check(await system.autopilot_type() == Autopilot.PX4, "it is a PX4 autopilot")
        tel, action = TelemetryAsync(system), ActionAsync(system)
        offboard, param = OffboardAsync(system), ParamAsync(system)
        await self.pace(system, param)

        async def healthy():
            h = await tel.health()
            return (h.is_local_position_ok and h.is_global_position_ok and h.is_home_position_ok
                    and h.is_armable)

        await self.until(healthy, "health: local and global position, home, armable")
        home = await tel.home()
        pos = await tel.position()
        self.check(abs(pos.relative_altitude_m) < 0.05 and abs(pos.latitude_deg - home.latitude_deg) < 1e-6
                   and abs(pos.longitude_deg - home.longitude_deg) < 1e-6,
                   f"position at home ({pos.latitude_deg:.7f}, {pos.longitude_deg:.7f}, "
                   f"{pos.relative_altitude_m:.3f} m up), home {home.latitude_deg:.7f}, "
                   f"{home.longitude_deg:.7f}")
        att = await tel.attitude_euler()
        self.check(abs(att.roll_deg) < 2 and abs(att.pitch_deg) < 2,
                   f"attitude level (roll {att.roll_deg:.2f}, pitch {att.pitch_deg:.2f} deg)")
        # The vehicle measures no battery and reports none (no modelled
        # pack passed off as measured): no BATTERY_STATUS, and SYS_STATUS's
        # voltage UINT16_MAX, MAVLink's "not sent". MAVSDK 4.1 reads that
        # as 65.535 V (it does not test for UINT16_MAX), or has nothing.
        try:
            bat = await asyncio.wait_for(tel.battery(), 3.0)
            none = math.isnan(bat.voltage_v) or abs(bat.voltage_v - 65.535) < 1e-3
            said = f"{bat.voltage_v:.3f} V, {bat.remaining_percent} %"
        except TimeoutError:
            none, said = True, "nothing in 3 s"
        self.check(none, f"no battery reported: MAVLink's 'not sent' ({said})")
        mode = await tel.flight_mode()
        self.check(mode == FlightMode.POSCTL, f"flight mode {mode} (Position)")
        landed = await tel.landed_state()
        self.check(landed == LandedState.ON_GROUND and not await tel.armed(),
                   f"landed state {landed}, disarmed")

        mass = await self.again(lambda: param.get_param_float("VEH_MASS"), "VEH_MASS")
        self.check(mass > 0, f"param VEH_MASS = {mass}")
        await self.again(lambda: param.set_param_float("MPC_XY_CRUISE", 1.0), "MPC_XY_CRUISE")
        cruise = await self.again(lambda: param.get_param_float("MPC_XY_CRUISE"), "MPC_XY_CRUISE")
        self.check(self.transfer(cruise == 1.0),
                   "param MPC_XY_CRUISE set and read back")
        # The whole list (PARAM_REQUEST_LIST): every parameter of the table,
        # once, the one just set with its new value.
        every = await self.again(param.get_all_params, "the parameter list")
        names = [p.name for p in every.float_params] + [p.name for p in every.int_params]
        cruise = [p.value for p in every.float_params if p.name == "MPC_XY_CRUISE"]
        self.check(self.transfer(len(names) == len(set(names)) == table_length() and cruise == [1.0]),
                   f"the parameter list downloaded whole: {len(names)} of {table_length()}, "
                   f"MPC_XY_CRUISE {cruise}")
        await self.again(lambda: action.set_takeoff_altitude(1.5), "the take-off height")
        height = await self.again(action.get_takeoff_altitude, "the take-off height")
        self.check(self.transfer(height == 1.5), "takeoff altitude 1.5 m (MIS_TAKEOFF_ALT)")

        async def mode_is(*m):
            return await tel.flight_mode() in m

        await self.command(action.arm, "arm", tel.armed)
        await self.until(tel.armed, "armed")

        await self.command(action.takeoff, "take-off", lambda: mode_is(FlightMode.TAKEOFF, FlightMode.HOLD))
        await self.until(lambda: mode_is(FlightMode.HOLD), "takeoff, then Hold")
        await self.settle_at([0.0, 0.0, -1.5], 0.05, 1.0, "rotorpy within 5 cm of 1.5 m up (1 s)")
        async def in_air():
            return await tel.landed_state() == LandedState.IN_AIR

        # Waited for: over a lossy link the last EXTENDED_SYS_STATE heard may be the take-off's.
        await self.until(in_air, "landed state IN_AIR")

        # The joystick, streamed at 20 Hz as MAVSDK's examples do.
        manual = ManualControlAsync(system)
        stick = [0.0, 0.0, 0.5, 0.0]
        streaming = True

        async def stream():
            while streaming:
                await manual.set_manual_control_input(*stick)
                await asyncio.sleep(0.05)

        task = asyncio.create_task(stream())
        await asyncio.sleep(0.5)
        await self.command(manual.start_position_control, "Position mode", lambda: mode_is(FlightMode.POSCTL))
        await self.until(lambda: mode_is(FlightMode.POSCTL), "joystick: Position mode")
        self.truth.poll()
        start = list(self.truth.pos)
        yaw = math.radians((await tel.attitude_euler()).yaw_deg)
        ahead = (math.cos(yaw), math.sin(yaw))  # forward, NED
        stick[0] = 0.6  # forward: (0.6 - 0.05) / 0.95 of MPC_VEL_MANUAL, 0.58 m/s
        low = [start[2]]

        def along():
            d = (self.truth.pos[0] - start[0], self.truth.pos[1] - start[1])
            return d[0] * ahead[0] + d[1] * ahead[1], d[1] * ahead[0] - d[0] * ahead[1]

        async def moved():
            low.append(self.truth.pos[2])
            return along()[0] >= 0.8

        await self.until(moved, f"joystick forward: rotorpy 0.8 m along its heading ({math.degrees(yaw):.0f} deg)")
        stick[0] = 0.0
        cross = abs(along()[1])
        dz = max(abs(z - start[2]) for z in low)
        self.check(cross < 0.1 and dz < 0.1, f"on its track and height: {100 * cross:.1f} cm across, "
                   f"{100 * dz:.1f} cm up or down (10 cm)")

        await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -1.5, 0.0))
        # MAVSDK streams it at 20 Hz from here; the switch is refused until
        # the vehicle has heard one (as PX4's): a second of the stream first,
        # so that a lossy link's burst does not swallow all it has sent.
        await asyncio.sleep(1.0)
        await self.command(offboard.start, "Offboard", lambda: mode_is(FlightMode.OFFBOARD))
        await self.until(lambda: mode_is(FlightMode.OFFBOARD), "offboard started")
        # The joystick goes quiet only once Offboard flies (its loss in
        # Position mode would land).
        streaming = False
        await task
        await offboard.set_position_ned(PositionNedYaw(2.0, 0.0, -1.5, 0.0))
        await self.settle_at([2.0, 0.0, -1.5], 0.05, 1.0, "offboard: rotorpy within 5 cm of 2 m north (1 s)")
        await self.command(offboard.stop, "Offboard's end", lambda: mode_is(FlightMode.HOLD))
        await self.until(lambda: mode_is(FlightMode.HOLD), "offboard stopped: Hold")

        # The mission: a 2 m square's corners and its centre, 1.5 m up,
        # as WGS-84 about home (the flight controller's flat earth,
        # WGS-84's equatorial radius).
        mission = MissionAsync(system)
        r = 6378137.0
        lat0, lon0 = home.latitude_deg, home.longitude_deg
        corners = [(2.0, 2.0), (0.0, 2.0), (0.0, 0.0), (1.0, 1.0)]
        items = [MissionItem(latitude_deg=lat0 + math.degrees(n / r),
                             longitude_deg=lon0 + math.degrees(e / (r * math.cos(math.radians(lat0)))),
                             relative_altitude_m=1.5, loiter_time_s=1.0, acceptance_radius_m=0.05)
                 for n, e in corners]
        await self.again(lambda: mission.upload_mission(MissionPlan(items)), "the mission's upload")
        back = await self.again(mission.download_mission, "the mission's download")
        self.check(self.transfer(len(back.mission_items) == 4 and all(
            abs(a.latitude_deg - b.latitude_deg) < 1e-7 and abs(a.relative_altitude_m - 1.5) < 1e-3
            for a, b in zip(back.mission_items, items))), "mission uploaded, downloaded back the same")
        since = len(self.truth.track)
        await self.command(mission.start_mission, "the mission's start", lambda: mode_is(FlightMode.MISSION))
        await self.until(lambda: mode_is(FlightMode.MISSION), "mission started")
        seen = set()

        async def finished():
            # MAVSDK's is_mission_finished() (and its progress' last step)
            # decides on the last MISSION_ITEM_REACHED, which the vehicle
            # sends once per item, as PX4 does: over a lossy link it can be
            # lost. The mission's end is then the mode, Hold, in every
            # HEARTBEAT.
            p = await mission.mission_progress()
            seen.add(p.current)
            return await mission.is_mission_finished() or (
                {1, 2, 3} <= seen and await tel.flight_mode() == FlightMode.HOLD)

        await self.until(finished, "mission finished", timeout=3 * self.timeout)
        p = await mission.mission_progress()
        end = "its last item reached" if p.current == 4 else "Hold (the last MISSION_ITEM_REACHED lost)"
        self.check(p.total == 4 and {1, 2, 3} <= seen and (p.current == 4 or await tel.flight_mode() == FlightMode.HOLD),
                   f"mission progress went through {sorted(seen)} of {p.total}, then {end}")
        for k, (n, e) in enumerate(corners):
            d = self.truth.closest([n, e, -1.5], since)
            self.check(d <= 0.05, f"waypoint {k + 1} ({n}, {e}, 1.5 m up): rotorpy within {100 * d:.1f} cm (5 cm)")

        await self.command(action.return_to_launch, "return to launch",
                           lambda: mode_is(FlightMode.RETURN_TO_LAUNCH, FlightMode.LAND))
        await self.until(lambda: mode_is(FlightMode.RETURN_TO_LAUNCH), "return to launch")

        async def down():
            return await tel.landed_state() == LandedState.ON_GROUND and not await tel.armed()

        await self.until(down, "landed and disarmed", timeout=3 * self.timeout)
        d = self.truth.dist([0.0, 0.0, 0.0])
        self.check(d <= 0.2, f"rotorpy landed {d:.3f} m from home (20 cm)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin://127.0.0.1:14550")
    ap.add_argument("--truth-port", type=int, default=14560)
    ap.add_argument("--timeout", type=float, default=60.0, help="wall seconds per step")
    ap.add_argument("--lossy", action="store_true",
                    help="the link loses datagrams: the vehicle's heartbeat asked for every 0.5 s of wall time")
    ap.add_argument("--transfers", metavar="NAME",
                    help="record the transfers' counts as NAME_transfers_{completed,failed,corrupted}")
    a = ap.parse_args()
    f = Flight(Truth(a.truth_port), a.timeout, lossy=a.lossy)
    try:
        asyncio.run(f.run(a.url))
    except Exception as e:  # noqa: BLE001 -- a MAVSDK error is a failed check, with its reason
        f.transfers["failed"] += 1
        f.check(False, f"MAVSDK raised {type(e).__name__}: {e}")
    t = f.transfers
    f.check(t["corrupted"] == 0, f"transfers: {t['completed']} completed exactly, {t['failed']} failed, "
                                 f"{t['corrupted']} corrupted")
    if a.transfers:
        for k, n in t.items():
            record(f"{a.transfers}_transfers_{k}", n, "transfers", "tools/rotorpy_hil.py --mavsdk --lossy")
    print(f.check.summary(say_failures=True), flush=True)
    return f.check.exit_code()


if __name__ == "__main__":
    sys.exit(main())
