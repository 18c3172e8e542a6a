#!/usr/bin/env python3
"""MAVProxy (PyPI), unmodified, scripted non-interactively against the
flight controller as against a PX4: its own PX4 mode table names the mode,
its parameter module lists and sets parameters, its mode, arm and takeoff
commands fly it. Run by tools/rotorpy_hil.py --mavproxy against
`sil-host px4-hil --gcs` flying rotorpy; rotorpy's truth arrives on
--truth-port as for tools/mavsdk_flight.py.

MAVProxy runs as a user runs it (`mavproxy.py --master=...`), its commands
written to its standard input and its console read back:

1. it connects and shows the mode PX4 would show (POSCTL); `signing setup
   PASSPHRASE` provisions a MAVLink signing key (SHA-256 of the passphrase)
   and MAVProxy signs from then on: every step below is a signed frame,
   which the vehicle would otherwise drop;
2. `param fetch` fetches every parameter (after its FTP attempts time out:
   the vehicle has no MAVLink FTP), `param show *` lists them;
   `param set` / `param show` one;
3. `mode` lists PX4's modes from pymavlink's table; `long DO_SET_MODE 1 4 3`
   (custom mode; AUTO.LOITER) switches to Hold, and the console shows
   LOITER. MAVProxy 1.8.75's own `mode LOITER` cannot switch a PX4: it
   hands pymavlink's (base, main, sub) tuple to `set_mode_px4` as one float
   ("required argument is not a float"), whatever the vehicle;
4. `arm throttle` arms; `takeoff 1.5` takes off: rotorpy holds 1.5 m within
   5 cm for 1 s (simulated) and the mode returns to LOITER;
5. `long DO_SET_MODE 1 4 5` (AUTO.RTL) brings it back: landed and disarmed
   within 20 cm of home.

MAVProxy writes its telemetry log and parameter file in a temporary
directory, not the caller's.

Prints `mavproxy check: P passed, F failed` and exits non-zero on a failure.
"""
import argparse
import math
import queue
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time

from fctools.checks import Checks
from fctools.truth import Truth


class Session:
    def __init__(self, url, truth, timeout):
        self.truth = truth
        self.timeout = timeout
        self.check = Checks("mavproxy", flush=True)
        self.lines = queue.Queue()
        self.seen = []
        self.dir = tempfile.mkdtemp(prefix="mavproxy-")
        self.p = subprocess.Popen(
            ["mavproxy.py", f"--master={url}", "--source-system=255"], cwd=self.dir,
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
        threading.Thread(target=self._read, daemon=True).start()

    def _take(self, line):
        """Keeps a console line (for later checks) and echoes it."""
        self.seen.append(line)
        print(f"  | {line}", flush=True)
        return line

    def _read(self):
        for line in self.p.stdout:
            self.lines.put(line.rstrip("\n"))

    def send(self, cmd):
        print(f"> {cmd}", flush=True)
        self.p.stdin.write(cmd + "\n")
        self.p.stdin.flush()

    def expect(self, pred, timeout=None):
        """The first console line (from now) for which `pred` holds, or None."""
        end = time.time() + (timeout or self.timeout)
        while time.time() < end:
            self.truth.poll()
            try:
                line = self.lines.get(timeout=0.1)
            except queue.Empty:
                continue
            if pred(self._take(line)):
                return line
        return None

    def near(self, ned, tol, hold_s=1.0, timeout=None):
        """rotorpy's position once it has stayed within `tol` of `ned` for
        `hold_s` simulated seconds, or None."""
        end = time.time() + (timeout or self.timeout)
        since = None
        while time.time() < end:
            self.truth.poll()
            p = self.truth.pos
            while not self.lines.empty():
                self._take(self.lines.get())
            if p is not None and math.dist(p, ned) <= tol:
                since = self.truth.t if since is None else since
                if self.truth.t - since >= hold_s:
                    return p
            else:
                since = None
            time.sleep(0.02)
        return None

    def run(self):
        self.check(self.expect(lambda l: "Detected vehicle" in l or "online system" in l) is not None,
                   "MAVProxy detects the vehicle")
        self.check(self.expect(lambda l: "POSCTL" in l, timeout=30) is not None,
                   "its console shows the mode PX4 would show: POSCTL")
        self.send("signing setup fc-owner-passphrase")
        self.check(self.expect(lambda l: "signing: key set" in l, timeout=30) is not None,
                   "signing setup: the vehicle holds the key, MAVProxy signs from here on")
        self.send("param fetch")
        # MAVProxy fetches them at connection too, and says so once it has
        # them all (a line may start with its prompt).
        def received(l):
            return re.search(r"Received \d+ parameters", l) is not None

        line = next((l for l in self.seen if received(l)), None) or self.expect(received)
        self.check(line is not None, f"param fetch: {line}")
        # `param show *` lists them all, one `NAME value` line each.
        count = int(re.search(r"Received (\d+)", line).group(1)) if line is not None else 0
        listed = set()

        def listing(l):
            m = re.search(r"([A-Z][A-Z0-9_]*)\s+(-?[0-9][0-9.eE+-]*)$", l)
            if m:
                listed.add(m.group(1))
            return count > 0 and len(listed) >= count

        self.send("param show *")
        self.expect(listing, timeout=10)
        self.check(count > 0 and len(listed) == count and {"MPC_XY_CRUISE", "COM_OF_LOSS_T", "VEH_MASS"} <= listed,
                   f"param show *: {len(listed)} of {count} listed")
        self.send("param set MPC_XY_CRUISE 0.8")
        # `param show` prints MAVProxy's copy, which the vehicle's answer updates.
        line = None
        for _ in range(10):
            self.send("param show MPC_XY_CRUISE")
            line = self.expect(lambda l: "MPC_XY_CRUISE" in l and "0.8" in l, timeout=3)
            if line is not None:
                break
        self.check(line is not None, f"param set and show: {line}")
        # MAVProxy lists PX4's modes from pymavlink's table.
        self.send("mode")
        line = self.expect(lambda l: "Available modes" in l and "LOITER" in l, timeout=5)
        self.check(line is not None, f"mode: {line}")
        # `long` sends any COMMAND_LONG: DO_SET_MODE, custom mode enabled,
        # AUTO (4) . LOITER (3), PX4's Hold.
        self.send("long DO_SET_MODE 1 4 3")
        self.check(self.expect(lambda l: "Mode LOITER" in l) is not None, "mode switched to LOITER (Hold)")
        for _ in range(60):
            self.send("arm throttle")
            if self.expect(lambda l: "ARMED" in l and "DISARMED" not in l, timeout=2) is not None:
                break
        self.check(any("ARMED" in l and "DISARMED" not in l for l in self.seen), "arm throttle: ARMED")
        self.send("takeoff 1.5")
        self.check(self.expect(lambda l: "Mode TAKEOFF" in l) is not None, "takeoff: mode TAKEOFF")
        # Only a LOITER line after the TAKEOFF line counts (the Hold switch
        # above printed one already).
        after_takeoff = len(self.seen)
        p = self.near([0.0, 0.0, -1.5], 0.05)
        self.check(p is not None, f"rotorpy within 5 cm of 1.5 m up for 1 s ({p})")
        self.check(any("Mode LOITER" in l for l in self.seen[after_takeoff:])
                   or self.expect(lambda l: "Mode LOITER" in l) is not None,
                   "then LOITER, after TAKEOFF")
        self.send("long DO_SET_MODE 1 4 5")
        self.check(self.expect(lambda l: "Mode RTL" in l) is not None, "mode RTL")
        line = self.expect(lambda l: "DISARMED" in l, timeout=3 * self.timeout)
        self.truth.poll()
        p = self.truth.pos
        d = math.dist(p, [0.0, 0.0, 0.0]) if p is not None else math.inf
        self.check(line is not None and d <= 0.2, f"landed and DISARMED {d:.3f} m from home (20 cm)")
        # The vehicle has no fence; MAVProxy's fence module reads a clear
        # GEOFENCE health bit in SYS_STATUS as a breach.
        self.check(not any("fence breach" in l for l in self.seen), "no fence breach reported")
        self.send("exit")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", default="udpin:127.0.0.1:14550")
    ap.add_argument("--truth-port", type=int, default=14560)
    ap.add_argument("--timeout", type=float, default=60.0, help="wall seconds per step")
    a = ap.parse_args()
    s = Session(a.url, Truth(a.truth_port), a.timeout)
    try:
        s.run()
    finally:
        if s.p.poll() is None:
            s.p.kill()
        shutil.rmtree(s.dir, ignore_errors=True)
    print(s.check.summary(say_failures=True), flush=True)
    return s.check.exit_code()


if __name__ == "__main__":
    sys.exit(main())
