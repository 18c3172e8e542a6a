#!/usr/bin/env python3
"""A ground station in a page of pymavlink, written from the MAVLink
specification (the parameter protocol, the command protocol, offboard
set-points), not from this project's code: it checks that the flight
controller can be operated as QGroundControl or a MAVSDK script would.

It listens on UDP (as QGroundControl does on 14550) for the vehicle's
heartbeat, then:

1. lists every parameter (PARAM_REQUEST_LIST → PARAM_VALUE × param_count)
   and reads one back by name (PARAM_REQUEST_READ);
2. writes a non-physical value (a negative mass): the write must be
   refused — the old value echoed in PARAM_VALUE and a STATUSTEXT naming
   the parameter —, then a valid one (failsafe timeout), a controller
   change and a weight of the flying controller (each re-designs it on
   board), all accepted;
3. arms (COMMAND_LONG MAV_CMD_COMPONENT_ARM_DISARM), retrying while the
   vehicle answers "temporarily rejected" (its estimator aligns first);
4. checks that a re-designing parameter (the mass, a gain) is refused
   while armed;
5. asks for PX4's Offboard mode (MAV_CMD_DO_SET_MODE): refused before
   any set-point, accepted once they stream; then
   streams SET_POSITION_TARGET_LOCAL_NED: 1 m up, then a step of
   --step m north; reads LOCAL_POSITION_NED, ATTITUDE and SYS_STATUS;
   the position must end within --tolerance of the set-point;
6. asks to disarm in the air (must be refused), then falls silent: no
   more heartbeats, as a ground station that is gone. The vehicle must
   say so, land where it is and disarm itself (its FS_GCS_MS failsafe).

It sends a HEARTBEAT (MAV_TYPE_GCS) every 0.5 s of wall time until then,
as QGroundControl does every second.

Prints one line `gcs check: P passed, F failed` (and what failed) and
exits non-zero if anything failed. Used by tools/rotorpy_hil.py --gcs.
"""
import argparse
import os
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

from fctools.checks import Checks

MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_DO_SET_MODE = 176
PX4_MAIN_OFFBOARD = 6.0
MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_FRAME_LOCAL_NED = 1
REAL32 = 9


class Gcs:
    def __init__(self, url, timeout, name="gcs"):
        self.check = Checks(name, flush=True)
        self.m = mavutil.mavlink_connection(url, source_system=254, source_component=190)
        self.timeout = timeout
        self.texts = []
        self.seen = {}
        self.boot_ms = 0
        self.position = None
        self.hb = None
        self.beating = True
        self.last_beat = 0.0

    def summary(self):
        """Prints `NAME check: P passed, F failed` (and what failed); the
        exit status: 1 if anything failed or nothing was checked."""
        print(self.check.summary(say_failures=True), flush=True)
        return self.check.exit_code()

    def recv(self, types, timeout=None):
        """The next message of one of `types`, keeping note of everything else."""
        end = time.time() + (timeout or self.timeout)
        while time.time() < end:
            if self.beating and time.time() - self.last_beat > 0.5:
                self.m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                self.last_beat = time.time()
            msg = self.m.recv_match(blocking=True, timeout=0.2)
            if msg is None:
                continue
            t = msg.get_type()
            self.seen[t] = self.seen.get(t, 0) + 1
            if t == "STATUSTEXT":
                self.texts.append(msg.text)
            if hasattr(msg, "time_boot_ms"):
                self.boot_ms = max(self.boot_ms, msg.time_boot_ms)
            if t == "LOCAL_POSITION_NED":
                self.position = (msg.x, msg.y, msg.z)
            if t == "HEARTBEAT":
                self.hb = msg
            if t in types:
                return msg
        return None

    def param_id(self, msg):
        pid = msg.param_id
        return pid.decode() if isinstance(pid, bytes) else pid

    def params(self):
        self.m.mav.param_request_list_send(self.sys, self.comp)
        values, count = {}, None
        end = time.time() + self.timeout
        while time.time() < end and (count is None or len(values) < count):
            msg = self.recv(["PARAM_VALUE"], timeout=2.0)
            if msg is None:
                break
            count = msg.param_count
            values[msg.param_index] = (self.param_id(msg), msg.param_value, msg.param_type)
        return count, values

    def set_param(self, name, value):
        """Writes `name` and returns the PARAM_VALUE the vehicle answers with."""
        self.m.mav.param_set_send(self.sys, self.comp, name.encode(), value, REAL32)
        end = time.time() + self.timeout
        while time.time() < end:
            msg = self.recv(["PARAM_VALUE"], timeout=2.0)
            if msg is not None and self.param_id(msg) == name:
                return msg
        return None

    def command(self, cmd, *params):
        p = list(params) + [0.0] * (7 - len(params))
        self.m.mav.command_long_send(self.sys, self.comp, cmd, 0, *p)
        end = time.time() + self.timeout
        while time.time() < end:
            ack = self.recv(["COMMAND_ACK"], timeout=2.0)
            if ack is not None and ack.command == cmd:
                return ack.result
        return None

    def setpoint(self, n, e, d):
        # Position only: velocity, acceleration and yaw rate ignored (bits 3-8, 11).
        mask = 0b0000_1001_1111_1000
        self.m.mav.set_position_target_local_ned_send(
            self.boot_ms, self.sys, self.comp, MAV_FRAME_LOCAL_NED, mask, n, e, d, 0, 0, 0, 0, 0, 0, 0.0, 0.0)

    def fly_to(self, target, sim_s):
        """Streams `target` at 20 Hz (wall) for `sim_s` of the vehicle's time."""
        start = None
        last = 0.0
        while True:
            if time.time() - last > 0.05:
                self.setpoint(*target)
                last = time.time()
            msg = self.recv(["LOCAL_POSITION_NED"], timeout=5.0)
            if msg is None:
                return False
            start = msg.time_boot_ms if start is None else start
            if msg.time_boot_ms - start >= sim_s * 1000:
                return True

    def run(self, step_m, tolerance_m):
        hb = self.recv(["HEARTBEAT"])
        if not self.check(hb is not None and hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR,
                          "a quadrotor's HEARTBEAT arrives"):
            return
        self.sys, self.comp = hb.get_srcSystem(), hb.get_srcComponent()

        count, values = self.params()
        names = [v[0] for v in values.values()]
        self.check(count and len(values) == count and len(set(names)) == count
                   and all(v[2] == REAL32 for v in values.values()),
                   f"PARAM_REQUEST_LIST: {len(values)} of {count} distinct REAL32 parameters")
        by_name = {v[0]: v[1] for v in values.values()}
        mass = by_name.get("VEH_MASS")
        self.m.mav.param_request_read_send(self.sys, self.comp, b"VEH_MASS", -1)
        msg = None
        for _ in range(20):
            msg = self.recv(["PARAM_VALUE"], timeout=2.0)
            if msg is None or self.param_id(msg) == "VEH_MASS":
                break
        self.check(msg is not None and mass is not None and msg.param_value == mass,
                   f"PARAM_REQUEST_READ VEH_MASS = {mass} kg")

        n_texts = len(self.texts)
        msg = self.set_param("VEH_MASS", -1.0)
        self.recv(["STATUSTEXT"], timeout=2.0)
        why = [t for t in self.texts[n_texts:] if "VEH_MASS" in t]
        self.check(msg is not None and msg.param_value == mass and why,
                   f"VEH_MASS = -1 refused, old value echoed, reason: {why[:1]}")
        msg = self.set_param("FS_TIMEOUT_MS", 80.0)
        self.check(msg is not None and msg.param_value == 80.0, "FS_TIMEOUT_MS = 80 accepted")
        ctl = by_name.get("CTL_ID")
        msg = self.set_param("CTL_ID", 2.0)
        ok = msg is not None and msg.param_value == 2.0
        msg = self.set_param("CTL_ID", ctl)
        self.check(ok and msg is not None and msg.param_value == ctl,
                   f"CTL_ID 2 then {ctl}: re-designed on board while disarmed")
        # A gain of the flying controller (the LQR's velocity weights ×1.5).
        msg = self.set_param("LQR_W_VEL", 1.5)
        self.check(msg is not None and msg.param_value == 1.5, "LQR_W_VEL = 1.5 accepted (LQR re-designed)")

        result = None
        end = time.time() + self.timeout
        while time.time() < end:
            result = self.command(MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
            if result != MAV_RESULT_TEMPORARILY_REJECTED:
                break
            time.sleep(0.2)
        self.check(result == MAV_RESULT_ACCEPTED, f"arm accepted (result {result})")
        hb = self.recv(["HEARTBEAT"])
        self.check(hb is not None and hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
                   "HEARTBEAT says armed")
        msg = self.set_param("VEH_MASS", mass * 1.1)
        self.check(msg is not None and msg.param_value == mass, "VEH_MASS refused while armed")
        roll_p = by_name.get("PD_ROLL_P")
        n_texts = len(self.texts)
        msg = self.set_param("PD_ROLL_P", 2.0 * roll_p if roll_p else 100.0)
        why = [t for t in self.texts[n_texts:] if "PD_ROLL_P" in t and "disarm" in t]
        self.check(msg is not None and msg.param_value == roll_p and why,
                   f"a gain (PD_ROLL_P) refused while armed: {why[:1]}")

        up, step = (0.0, 0.0, -1.0), (step_m, 0.0, -1.0)
        # PX4's rule: set-points are flown in Offboard, which is entered
        # only while they stream.
        self.check(self.command(MAV_CMD_DO_SET_MODE, 1.0, PX4_MAIN_OFFBOARD, 0.0) == MAV_RESULT_DENIED,
                   "Offboard refused before any set-point")
        self.fly_to(up, 0.2)
        self.check(self.command(MAV_CMD_DO_SET_MODE, 1.0, PX4_MAIN_OFFBOARD, 0.0) == MAV_RESULT_ACCEPTED,
                   "Offboard accepted while set-points stream")
        self.check(self.fly_to(up, 4.0), "1 m up, held 4 s of vehicle time")
        self.check(self.fly_to(step, 6.0), f"{step_m} m north, held 6 s")
        err = None
        if self.position is not None:
            err = sum((a - b) ** 2 for a, b in zip(self.position, step)) ** 0.5
        self.check(err is not None and err <= tolerance_m,
                   f"LOCAL_POSITION_NED {self.position} within {tolerance_m} m of {step} (error {err})")
        span_s = max(self.boot_ms, 1) / 1000.0
        for t, lo in (("ATTITUDE", 20.0), ("LOCAL_POSITION_NED", 20.0), ("SYS_STATUS", 0.5)):
            rate = self.seen.get(t, 0) / span_s
            self.check(rate >= lo, f"{t} at {rate:.1f} Hz of vehicle time (at least {lo})")
        self.check(self.command(MAV_CMD_COMPONENT_ARM_DISARM, 0.0) == MAV_RESULT_DENIED, "disarm in the air denied")
        # Gone: no more heartbeats. The vehicle must land and disarm by itself.
        self.beating = False
        n_texts = len(self.texts)
        disarmed = False
        end = time.time() + 4 * self.timeout
        while time.time() < end and not disarmed:
            hb = self.recv(["HEARTBEAT"], timeout=5.0)
            disarmed = hb is not None and not hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        said = self.texts[n_texts:]
        self.check(disarmed and "ground station lost: landing" in said and "landed: disarmed" in said,
                   f"silent ground station: landed and disarmed by itself ({said})")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin:127.0.0.1:14550")
    ap.add_argument("--timeout", type=float, default=60.0, help="wall seconds per exchange")
    ap.add_argument("--step", type=float, default=0.5, help="m north")
    ap.add_argument("--tolerance", type=float, default=0.05, help="m")
    a = ap.parse_args()
    g = Gcs(a.url, a.timeout)
    g.run(a.step, a.tolerance)
    return g.summary()


if __name__ == "__main__":
    sys.exit(main())
