#!/usr/bin/env python3
"""MAVLink 2 signing, tried with pymavlink as an owner and an intruder
would, against the vehicle flying in rotorpy (tools/rotorpy_hil.py
--signing). Written from mavlink.io's "Message Signing" and PX4's "MAVLink
Message Signing" pages, not from this project's code.

The owner listens on UDP (as QGroundControl does) for the vehicle's
heartbeat, then:

1. provisions a key with SETUP_SIGNING (unsigned: no key is set yet) and
   signs from then on; the vehicle's frames must now verify with the key
   (pymavlink drops any that do not);
2. an intruder on another UDP port, unsigned, then one signing with a wrong
   key, tries to arm, to switch mode, to set a parameter, to upload a
   mission and to replace the key: the vehicle's state (read by the owner)
   must show that nothing happened;
3. the owner arms, takes off and, while it flies, the intruder sends a
   forced disarm (PX4's 21196): the vehicle must stay armed and in the air;
4. the owner lands; the vehicle disarms itself on the ground; the
   intruder replays the owner's signed arm frame, byte for byte: ignored;
5. the owner clears the key with a signed all-zero SETUP_SIGNING.

With `--keep FILE` (the vehicle runs with `sil-host px4-hil --storage`) the
owner then provisions a second key and sets a parameter, and writes both,
with the last signature timestamp it saw from the vehicle, to FILE. With
`--after-restart FILE`, against the vehicle started again on the same
storage, it checks that the vehicle signs nothing until it hears a frame
signed with the kept key (it sends only its HEARTBEAT, unsigned; an
unsigned parameter read and arm go unanswered), that its first frame then verifies with the key with a
timestamp above the last one the owner saw from it, and that the parameter
kept its value. With `--cut FILE` the owner flies on
that key and, in the air, notes the vehicle's last signature timestamp in
FILE; the flight controller is then killed there (`rotorpy_hil.py --cut`,
a power cut in flight), and `--after-restart` checks that the vehicle's
first frame after it is signed above that timestamp.

In process (`sil-host px4-hil`) the host's link checks and signs; with
`--target qemu` the host forwards the ground station's frames whole and
`firmware-mavlink` checks and signs them itself.

Prints one line `signing check: P passed, F failed` (and what failed) and
exits non-zero if anything failed.
"""
import argparse
import json
import os
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

from mav_gcs import Gcs

ARM_DISARM = 400
DO_SET_MODE = 176
NAV_TAKEOFF = 22
NAV_LAND = 21
FORCE = 21196.0
ACCEPTED, TEMPORARILY_REJECTED = 0, 1
ARMED = mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED
REAL32 = 9
# PX4's Hold (main mode AUTO, sub mode LOITER), as DO_SET_MODE's param2, param3.
HOLD = (4.0, 3.0)
KEY = bytes(range(0x40, 0x60))
WRONG_KEY = bytes(range(0x41, 0x61))
# The key kept across a restart (--keep, --after-restart).
KEPT_KEY = bytes(range(0x80, 0xA0))


def now_2015():
    """A signing timestamp: 10 µs units since 2015-01-01 00:00 UTC."""
    return int((time.time() - 1420070400) * 100000)


class Session(Gcs):
    """mav_gcs.py's ground station, as the owner; its `recv` keeps the last
    HEARTBEAT and LOCAL_POSITION_NED (verified, once signing is on)."""

    @property
    def z(self):
        return None if self.position is None else self.position[2]

    def settle(self, seconds):
        """Reads for `seconds` (wall), keeping the latest state."""
        end = time.time() + seconds
        while time.time() < end:
            self.recv([], timeout=max(0.05, end - time.time()))

    def armed(self, beats=2):
        """Armed, by the `beats`-th heartbeat from now: the first may have
        left before what was just sent arrived (1 Hz of vehicle time)."""
        for _ in range(beats):
            self.recv(["HEARTBEAT"], timeout=30.0)
        return self.hb is not None and bool(self.hb.base_mode & ARMED)

    def until(self, pred, timeout=None):
        """Heartbeats until `pred(heartbeat)` holds (True) or `timeout`."""
        end = time.time() + (timeout or self.timeout)
        while time.time() < end:
            hb = self.recv(["HEARTBEAT"], timeout=5.0)
            if hb is not None and pred(hb):
                return True
        return False

    def param(self, name):
        self.m.mav.param_request_read_send(self.sys, self.comp, name.encode(), -1)
        for _ in range(50):
            msg = self.recv(["PARAM_VALUE"], timeout=2.0)
            if msg is None:
                return None
            pid = msg.param_id.decode() if isinstance(msg.param_id, bytes) else msg.param_id
            if pid == name:
                return msg.param_value
        return None

    def mission_count(self):
        self.m.mav.mission_request_list_send(self.sys, self.comp, 0)
        msg = self.recv(["MISSION_COUNT"], timeout=5.0)
        return None if msg is None else msg.count

    def intruder(self, key):
        """A second ground station on its own UDP port, at the vehicle's
        address (where the owner hears it from); signing with `key` if given."""
        host, port = next(iter(self.m.clients))
        i = mavutil.mavlink_connection(f"udpout:{host}:{port}", source_system=66, source_component=190)
        if key is not None:
            i.setup_signing(key, sign_outgoing=True, initial_timestamp=now_2015(), link_id=7)
        return i

    def attempts(self, i, who):
        """Everything an intruder tries while the vehicle is on the ground."""
        fs = self.param("FS_TIMEOUT_MS")
        missions = self.mission_count()
        mode = self.hb.custom_mode
        n_requests = 0
        i.mav.command_long_send(self.sys, self.comp, ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        i.mav.command_long_send(self.sys, self.comp, DO_SET_MODE, 0, 1, *HOLD, 0, 0, 0, 0)
        i.mav.param_set_send(self.sys, self.comp, b"FS_TIMEOUT_MS", fs + 100.0, REAL32)
        i.mav.mission_count_send(self.sys, self.comp, 1, 0)
        i.mav.setup_signing_send(self.sys, self.comp, list(WRONG_KEY), now_2015())
        end = time.time() + 2.0
        while time.time() < end:
            if self.recv(["MISSION_REQUEST_INT", "MISSION_REQUEST"], timeout=0.3) is not None:
                n_requests += 1
        self.check(not self.armed(), f"{who}: arm ignored (still disarmed)")
        self.check(self.hb.custom_mode == mode, f"{who}: mode change ignored (custom mode {mode:#x})")
        after = self.param("FS_TIMEOUT_MS")
        self.check(after == fs, f"{who}: FS_TIMEOUT_MS write ignored ({after}, was {fs})")
        self.check(n_requests == 0 and self.mission_count() == missions,
                   f"{who}: mission upload ignored (no MISSION_REQUEST, {missions} items)")
        # The owner still hears verified frames: the key was not replaced.
        self.check(self.recv(["HEARTBEAT"], timeout=30.0) is not None, f"{who}: SETUP_SIGNING ignored (key kept)")

    def run(self):
        hb = self.recv(["HEARTBEAT"])
        if not self.check(hb is not None, "the vehicle's HEARTBEAT arrives (unsigned: no key yet)"):
            return
        self.sys, self.comp = hb.get_srcSystem(), hb.get_srcComponent()
        self.check(not getattr(hb, "_signed", False), "its frames are unsigned before a key is set")

        ts = now_2015()
        self.m.mav.setup_signing_send(self.sys, self.comp, list(KEY), ts)
        self.m.setup_signing(KEY, sign_outgoing=True, initial_timestamp=ts, link_id=0)
        n = len(self.texts)
        # 30 s of wall time, as every other heartbeat wait here: the image in
        # QEMU beats at 1 Hz of its own time, which runs at a sixth of wall
        # time or slower in lockstep with rotorpy (10 s missed it once in CI).
        # pymavlink drops unsigned frames from here on: what arrives is verified.
        hb = self.recv(["HEARTBEAT"], timeout=30.0)
        self.check(hb is not None and getattr(hb, "_signed", False),
                   "after SETUP_SIGNING the vehicle's frames verify with the key")
        self.settle(0.5)
        self.check(any("key set" in t for t in self.texts[n:]), f"it says so: {self.texts[n:][:1]}")

        for key, who in ((None, "unsigned intruder"), (WRONG_KEY, "intruder with a wrong key")):
            i = self.intruder(key)
            self.attempts(i, who)
            i.close()
        # The same requests from the owner, signed, are obeyed: the checks
        # above could fail.
        self.check(self.command(DO_SET_MODE, 1, *HOLD) == ACCEPTED
                   and self.until(lambda hb: hb.custom_mode >> 16 == 0x0304),
                   f"owner (signed): Hold accepted (custom mode {self.hb.custom_mode:#x})")
        fs = self.param("FS_TIMEOUT_MS")
        self.m.mav.param_set_send(self.sys, self.comp, b"FS_TIMEOUT_MS", fs + 100.0, REAL32)
        self.settle(0.5)
        self.check(self.param("FS_TIMEOUT_MS") == fs + 100.0, "owner (signed): FS_TIMEOUT_MS write accepted")

        result = None
        end = time.time() + self.timeout
        while time.time() < end:
            # Packed by hand to keep its bytes: the intruder replays them later.
            msg = self.m.mav.command_long_encode(self.sys, self.comp, ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            arm_frame = msg.pack(self.m.mav)
            self.m.mav.seq = (self.m.mav.seq + 1) % 256
            self.m.write(arm_frame)
            ack = None
            while ack is None or ack.command != ARM_DISARM:
                ack = self.recv(["COMMAND_ACK"], timeout=3.0)
                if ack is None:
                    break
            result = None if ack is None else ack.result
            if result != TEMPORARILY_REJECTED:
                break
            time.sleep(0.2)
        self.take_off(result, "owner (signed)")
        self.check(self.z is not None and self.z <= -0.8, f"climbing: {self.z} m down")

        i = self.intruder(None)
        i.mav.command_long_send(self.sys, self.comp, ARM_DISARM, 0, 0, FORCE, 0, 0, 0, 0, 0)
        i.mav.command_long_send(self.sys, self.comp, NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
        self.settle(1.5)
        self.check(self.armed() and self.z is not None and self.z < -0.5,
                   f"intruder's forced disarm and land in flight ignored: armed, {self.z} m down")

        self.check(self.command(NAV_LAND) == ACCEPTED, "owner: land accepted")
        n = len(self.texts)
        end = time.time() + 4 * self.timeout
        while time.time() < end and self.armed(beats=1):
            pass
        self.check(not self.armed(), f"landed and disarmed ({self.texts[n:]})")
        i.write(arm_frame)
        self.settle(1.5)
        self.check(not self.armed(), "the owner's signed arm, replayed by the intruder: ignored")
        i.close()

        n = len(self.texts)
        self.m.mav.setup_signing_send(self.sys, self.comp, [0] * 32, 0)
        # Its answer comes unsigned: the key is gone.
        self.m.mav.signing.allow_unsigned_callback = lambda mav, msg_id: True
        self.settle(1.0)
        self.check(any("key cleared" in t for t in self.texts[n:]),
                   f"owner: a signed blank SETUP_SIGNING clears the key ({self.texts[n:][:1]})")

    def take_off(self, arm_result, who):
        """Checks the arm (`arm_result`, its ack) took, asks for a take-off
        to 1 m and reads positions until 0.8 m up (or the timeout)."""
        self.check(arm_result == ACCEPTED and self.until(lambda hb: hb.base_mode & ARMED),
                   f"{who}: arm accepted (result {arm_result})")
        self.check(self.command(NAV_TAKEOFF, 0, 0, 0, float("nan"), 0, 0, 1.0) == ACCEPTED,
                   "owner: take-off accepted")
        end = time.time() + self.timeout
        while time.time() < end and (self.z is None or self.z > -0.8):
            self.recv(["LOCAL_POSITION_NED"], timeout=2.0)

    def vehicle_timestamp(self):
        """The last signature timestamp verified on the vehicle's frames."""
        ts = [t for (_, sysid, _), t in self.m.mav.signing.stream_timestamps.items() if sysid == self.sys]
        return max(ts) if ts else None

    def keep(self, path):
        """A second key and a parameter, for the vehicle to keep (--storage)."""
        self.m.mav.signing.allow_unsigned_callback = None
        ts = now_2015()
        self.m.mav.setup_signing_send(self.sys, self.comp, list(KEPT_KEY), ts)
        self.m.setup_signing(KEPT_KEY, sign_outgoing=True, initial_timestamp=ts, link_id=0)
        hb = self.recv(["HEARTBEAT"], timeout=30.0)
        self.check(hb is not None and getattr(hb, "_signed", False), "a second key set: frames verify with it")
        fs = self.param("FS_TIMEOUT_MS")
        self.m.mav.param_set_send(self.sys, self.comp, b"FS_TIMEOUT_MS", fs + 200.0, REAL32)
        self.settle(0.5)
        kept = self.param("FS_TIMEOUT_MS")
        self.check(kept == fs + 200.0, f"FS_TIMEOUT_MS set to {kept}, to be kept")
        self.settle(1.0)
        with open(path, "w") as f:
            json.dump({"FS_TIMEOUT_MS": kept, "default": fs, "timestamp": self.vehicle_timestamp(),
                       "sys": self.sys, "comp": self.comp}, f)

    def cut(self, path):
        """The owner, with the key `keep` left, arms and takes off; in the
        air it adds the last timestamp it verified on the vehicle's frames to
        `path` and stops, for the flight controller to be killed there (a
        power cut in flight)."""
        with open(path) as f:
            kept = json.load(f)
        # Booted on the stored key, it answers only once it hears the owner.
        self.m.setup_signing(KEPT_KEY, sign_outgoing=True, initial_timestamp=now_2015(), link_id=0)
        hb = self.recv(["HEARTBEAT"])
        if not self.check(hb is not None and getattr(hb, "_signed", False), "the vehicle's HEARTBEAT arrives, signed"):
            return
        self.sys, self.comp = hb.get_srcSystem(), hb.get_srcComponent()
        # Refused for now until the estimator has aligned at rest.
        result, end = None, time.time() + self.timeout
        while time.time() < end and result in (None, TEMPORARILY_REJECTED):
            result = self.command(ARM_DISARM, 1)
            if result == TEMPORARILY_REJECTED:
                time.sleep(0.2)
        self.take_off(result, "owner (signed, the kept key)")
        self.settle(2.0)
        ts = self.vehicle_timestamp()
        self.check(self.armed() and self.z is not None and self.z < -0.5 and ts is not None,
                   f"in the air ({self.z} m down, armed), the vehicle's last timestamp {ts}: the power is cut now")
        kept.update(timestamp=ts, cut=True)
        with open(path, "w") as f:
            json.dump(kept, f)

    def after_restart(self, path):
        """The vehicle started again on the storage `keep` (or `cut`) wrote to."""
        with open(path) as f:
            kept = json.load(f)
        self.sys, self.comp = kept["sys"], kept["comp"]
        # Its frames verified (pymavlink from timestamp 0 takes a stream
        # however far behind it is), ours not signed yet.
        self.m.setup_signing(KEPT_KEY, sign_outgoing=False, initial_timestamp=0, link_id=0,
                             allow_unsigned_callback=lambda mav, msg_id: msg_id == 0)
        self.settle(3.0)
        self.m.mav.param_request_read_send(self.sys, self.comp, b"FS_TIMEOUT_MS", -1)
        self.m.mav.command_long_send(self.sys, self.comp, ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        self.settle(1.5)
        self.check(self.hb is not None and not getattr(self.hb, "_signed", True) and not self.seen.get("PARAM_VALUE")
                   and self.vehicle_timestamp() is None and sorted(self.seen) == ["HEARTBEAT"],
                   "booted on the stored key, it signs nothing until a frame signed with the key is heard: only "
                   f"its HEARTBEAT, unsigned; an unsigned parameter read and arm go unanswered (heard {sorted(self.seen)})")
        self.m.mav.signing.allow_unsigned_callback = None
        self.m.mav.signing.sign_outgoing = True
        self.m.mav.signing.timestamp = max(self.m.mav.signing.timestamp, now_2015())
        hb = self.recv(["HEARTBEAT"], timeout=30.0)
        first = self.vehicle_timestamp()
        before = "the last seen in flight before the power cut" if kept.get("cut") else "the last seen before"
        self.check(hb is not None and getattr(hb, "_signed", False) and first is not None
                   and kept["timestamp"] is not None and first > kept["timestamp"],
                   f"once the owner signs, its first frame verifies with the kept key, its timestamp {first} "
                   f"above {kept['timestamp']} ({before})")
        self.check(not self.armed(), "the unsigned arm was ignored")
        value = self.param("FS_TIMEOUT_MS")
        self.check(value == kept["FS_TIMEOUT_MS"] and value != kept["default"],
                   f"FS_TIMEOUT_MS kept: {value} (default {kept['default']})")
        self.check(self.command(ARM_DISARM, 1) == ACCEPTED and self.armed(), "owner (signed): arm accepted")
        self.check(self.command(ARM_DISARM, 0) == ACCEPTED and not self.armed(), "owner: disarm accepted")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin:127.0.0.1:14550")
    ap.add_argument("--timeout", type=float, default=60.0, help="wall seconds per exchange")
    ap.add_argument("--keep", metavar="FILE", help="then set a key and a parameter to keep; note them in FILE")
    ap.add_argument("--after-restart", metavar="FILE", help="only check what --keep (or --cut) left in FILE")
    ap.add_argument("--cut", metavar="FILE", help="only fly with the key --keep left, to be cut off in the air; "
                                                  "note the vehicle's last timestamp in FILE")
    a = ap.parse_args()
    s = Session(a.url, a.timeout, name="signing")
    if a.after_restart:
        s.after_restart(a.after_restart)
    elif a.cut:
        s.cut(a.cut)
    else:
        s.run()
        if a.keep:
            s.keep(a.keep)
    return s.summary()


if __name__ == "__main__":
    sys.exit(main())
