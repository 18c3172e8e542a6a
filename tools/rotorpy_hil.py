#!/usr/bin/env python3
"""Fly the flight-controller core against rotorpy (PyPI `rotorpy`, MIT), a
multirotor simulator this project did not write, over PX4's HIL interface.

rotorpy's `PX4Multirotor` listens on tcpin:localhost:4560, sends
HIL_STATE_QUATERNION and HIL_SENSOR every step and applies the
HIL_ACTUATOR_CONTROLS it gets back (motor speeds as fractions of its
maximum), with its own aerodynamics (rotor drag, induced inflow) and motor
lag. `sil-host px4-hil` is the flight controller: it connects, aligns its
estimator at rest on the ground, arms and flies the waypoints.

    python3 tools/rotorpy_hil.py --sil-host target/release/sil-host \
        --waypoint 0,0,0,-1 --waypoint 6,1,0,-1 --duration 12

Prints the flight controller's JSON summary with this script's own
measurements of the flight (from rotorpy's true state) added under
"rotorpy"; exits non-zero if the vehicle diverged or ended further than
--max-final-error from the last waypoint.
"""
import argparse
import importlib.metadata
import json
import platform
import os
import socket
import subprocess
import sys

# pymavlink speaks MAVLink 1 unless told otherwise before it is imported;
# the flight controller reads MAVLink 2 only.
os.environ["MAVLINK20"] = "1"

import numpy as np  # noqa: E402
from children import EndsWithFlight  # noqa: E402
from measure import record  # noqa: E402
from rotorpy.vehicles.crazyflie_params import quad_params as crazyflie_params  # noqa: E402
from rotorpy.vehicles.hummingbird_params import quad_params as hummingbird_params  # noqa: E402
from rotorpy.vehicles.px4_multirotor import PX4Multirotor  # noqa: E402


# Motor layouts as each vendor numbers its motors: (forward, right) hub position
# in units of the hub's x/y offset (the Crazyflie's 43 mm hubs at 45°: 30.4 mm),
# and the spin seen from above (CW / CCW). Written from the vendors' own
# references: PX4's airframe reference ("Quadrotor x"), Betaflight's motor tab
# (Quad X, props in), the Crazyflie firmware's M1-M4; rotorpy's own Crazyflie
# order; and the OS4's "+" (docs/book/src/model.md §3) at the same moment arm.
LAYOUTS = {
    "rotorpy": ("x-rotorpy", [(1, -1, "CW"), (1, 1, "CCW"), (-1, 1, "CW"), (-1, -1, "CCW")]),
    "px4": ("x-px4", [(1, 1, "CCW"), (-1, -1, "CCW"), (1, -1, "CW"), (-1, 1, "CW")]),
    "betaflight": ("x-betaflight", [(-1, 1, "CW"), (1, 1, "CCW"), (-1, -1, "CCW"), (1, -1, "CW")]),
    "crazyflie": ("x-crazyflie", [(1, 1, "CCW"), (-1, 1, "CW"), (-1, -1, "CCW"), (1, -1, "CW")]),
    "plus": ("plus", [(1, 0, "CCW"), (0, 1, "CW"), (-1, 0, "CCW"), (0, -1, "CW")]),
}


# rotorpy's vehicles and our vehicle files for them (vehicles/).
VEHICLES = {
    "crazyflie": (crazyflie_params, "vehicles/crazyflie-rotorpy.toml"),
    "hummingbird": (hummingbird_params, "vehicles/hummingbird-rotorpy.toml"),
}


def params_for(vehicle, layout):
    """rotorpy's `vehicle` with its motors in `layout`'s order. rotorpy's body
    frame is FLU (y left) and its rotor direction +1 is clockwise from above
    (its own Crazyflie: r1 front-left +1, r2 front-right -1, …)."""
    quad_params = VEHICLES[vehicle][0]
    q = dict(quad_params)
    d = quad_params["rotor_pos"]["r1"][0]
    rotors = LAYOUTS[layout][1]
    q["rotor_pos"] = {f"r{i + 1}": np.array([x * d, -y * d, 0.0]) for i, (x, y, _) in enumerate(rotors)}
    q["rotor_directions"] = np.array([1 if spin == "CW" else -1 for (_, _, spin) in rotors])
    return q


class Lockstep(PX4Multirotor):
    """rotorpy's vehicle, waiting as long as it takes for the flight
    controller's answer (its own waits 10 ms of wall time and then flies
    with the motors off: a flight controller in an emulator is slower)."""

    def _fetch_latest_px4_control(self, blocking=True):
        msg = self.conn.recv_match(type="HIL_ACTUATOR_CONTROLS", blocking=True, timeout=30.0)
        if msg is None:
            raise RuntimeError("no HIL_ACTUATOR_CONTROLS from the flight controller in 30 s")
        return {"cmd_motor_speeds": [c * self.rotor_speed_max for c in msg.controls[: self.num_rotors]]}


# The packages a flight's figures depend on, recorded in its JSON: the same
# versions (tools/requirements.txt) fly the same bits.
FLOWN_WITH = ("numpy", "scipy", "rotorpy", "pymavlink", "mavsdk", "MAVProxy")


def versions():
    out = {"python": platform.python_version()}
    for name in FLOWN_WITH:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sil-host", default="target/release/sil-host")
    ap.add_argument("--controller", default="lqr")
    ap.add_argument("--target", default="in-process", help="in-process | qemu (the firmware-mavlink image)")
    ap.add_argument("--waypoint", action="append", help="T,N,E,D (NED about the start, m)")
    ap.add_argument("--scenario", help="circle | helix: its trajectory from --scenario-start s (RMSE reported)")
    ap.add_argument("--scenario-start", type=float, default=3.0)
    ap.add_argument("--duration", type=float, default=12.0, help="simulated seconds")
    ap.add_argument("--dt", type=float, default=0.002, help="rotorpy's step, s")
    ap.add_argument("--port", type=int, default=4560)
    ap.add_argument("--max-final-error", type=float, default=0.05, help="m (waypoints)")
    ap.add_argument("--max-rmse", type=float, default=0.15, help="m (scenario tracking, 3-D)")
    ap.add_argument("--csv", help="the flight controller's trace")
    ap.add_argument("--ulog", help="the flight as a ULog (sil-host px4-hil --ulog)")
    ap.add_argument("--json", help="write the summary here too")
    ap.add_argument("--measure", metavar="NAME",
                    help="write the flight's figures to the measurements (tools/measure.py) as rotorpy_NAME_*")
    ap.add_argument("--seed", type=int, default=1, help="seeds rotorpy's IMU noise (numpy)")
    ap.add_argument("--gcs", action="store_true",
                    help="no mission: tools/mav_gcs.py (a pymavlink ground station on UDP 14550) "
                         "sets parameters, arms and flies the vehicle; the flight ends when it is done")
    ap.add_argument("--gcs-port", type=int, default=14550)
    ap.add_argument("--mavsdk", action="store_true",
                    help="like --gcs, with tools/mavsdk_flight.py (MAVSDK, PyPI) as the ground station; "
                         "rotorpy's position is sent to it on UDP --truth-port")
    ap.add_argument("--mavproxy", action="store_true",
                    help="like --mavsdk, with tools/mavproxy_session.py (MAVProxy, PyPI) as the ground station")
    ap.add_argument("--truth-port", type=int, default=14560)
    ap.add_argument("--vehicle", choices=sorted(VEHICLES), default="crazyflie",
                    help="rotorpy's vehicle, flown with our vehicle file for it")
    ap.add_argument("--layout", choices=sorted(LAYOUTS), default="rotorpy",
                    help="rotorpy's motors in this vendor's order, and the flight controller told so "
                         "(--airframe, MOT_FRAME)")
    ap.add_argument("--param", action="append", metavar="NAME=VALUE",
                    help="a flight-controller parameter set before the flight (repeatable)")
    a = ap.parse_args()

    cmd = [a.sil_host, "px4-hil", "--connect", f"127.0.0.1:{a.port}", "--controller", a.controller,
           "--vehicle", VEHICLES[a.vehicle][1], "--airframe", LAYOUTS[a.layout][0],
           "--hub-m", str(VEHICLES[a.vehicle][0]["rotor_pos"]["r1"][0] * 2 ** 0.5),
           "--motor-unit", "speed", "--duration", str(a.duration + 1.0), "--target", a.target]
    if (bool(a.waypoint) + bool(a.scenario) + a.gcs + a.mavsdk + a.mavproxy) != 1:
        ap.error("give --waypoint(s), --scenario, --gcs, --mavsdk or --mavproxy")
    gcs = None
    truth_sock = None
    here = os.path.dirname(__file__)
    if a.gcs or a.mavsdk or a.mavproxy:
        # The ground station listens first, as QGroundControl does.
        if a.mavsdk or a.mavproxy:
            # MAVSDK's URL and MAVProxy's (pymavlink's) spell UDP differently.
            name, url = (("mavsdk_flight.py", f"udpin://127.0.0.1:{a.gcs_port}") if a.mavsdk
                         else ("mavproxy_session.py", f"udpin:127.0.0.1:{a.gcs_port}"))
            script = [os.path.join(here, name), "--url", url, "--truth-port", str(a.truth_port)]
            if a.target == "qemu":
                # The image in QEMU flies about 5x slower than real time.
                script += ["--timeout", "180"]
            truth_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        else:
            script = [os.path.join(here, "mav_gcs.py"), "--url", f"udpin:127.0.0.1:{a.gcs_port}"]
        gcs = subprocess.Popen([sys.executable] + script, stdout=subprocess.PIPE, text=True)
        cmd += ["--gcs", f"127.0.0.1:{a.gcs_port}", "--gcs-only"]
    for w in a.waypoint or []:
        cmd += ["--waypoint", w]
    for p in a.param or []:
        cmd += ["--param", p]
    if a.scenario:
        cmd += ["--scenario", a.scenario, "--scenario-start", str(a.scenario_start)]
    if a.csv:
        cmd += ["--csv", a.csv]
    if a.ulog:
        cmd += ["--ulog", a.ulog]
    np.random.seed(a.seed)
    fc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
    fc_watch = EndsWithFlight(fc, "sil-host px4-hil")
    vehicle = Lockstep(params_for(a.vehicle, a.layout), mavlink_url=f"tcpin:localhost:{a.port}")
    state = dict(vehicle.initial_state)
    zero = {"cmd_motor_speeds": np.zeros(4)}
    track = []
    steps = int(round(a.duration / a.dt))
    for k in range(steps):
        state = vehicle.step(state, zero, a.dt)
        x = np.asarray(state["x"], dtype=float)  # ENU
        track.append([k * a.dt, x[1], x[0], -x[2]])  # t, north, east, down
        if truth_sock is not None and k % 10 == 0:
            msg = json.dumps({"t": k * a.dt, "ned": track[-1][1:]}).encode()
            truth_sock.sendto(msg, ("127.0.0.1", a.truth_port))
        if not np.all(np.isfinite(x)) or np.abs(x).max() > 100:
            break
        if gcs is not None and k % 50 == 0 and gcs.poll() is not None:
            break
    # Hanging up ends the flight controller's session (and its summary).
    fc_watch.done()
    vehicle.conn.close()
    out, _ = fc.communicate(timeout=60)
    if fc.returncode != 0:
        print(f"sil-host px4-hil failed ({fc.returncode})", file=sys.stderr)
        return 1
    res = json.loads(out)
    res["versions"] = versions()
    track = np.array(track)
    if gcs is not None:
        if gcs.poll() is None:
            gcs.kill()
        gcs_out, _ = gcs.communicate(timeout=60)
        sys.stderr.write(gcs_out)
        prefix = "mavsdk check:" if a.mavsdk else "mavproxy check:" if a.mavproxy else "gcs check:"
        line = [ln for ln in gcs_out.splitlines() if ln.startswith(prefix)]
        res["gcs"] = line[-1] if line else f"{prefix} 0 passed, 1 failed (the ground station did not finish)"
        text = json.dumps(res, indent=2)
        print(text)
        if a.json:
            with open(a.json, "w") as f:
                f.write(text + "\n")
        print(res["gcs"])
        return 0 if gcs.returncode == 0 and line else 1
    final = track[-1, 1:4]
    if a.waypoint:
        n, e, d = (float(v) for v in a.waypoint[-1].split(",")[1:4])
        err = float(np.linalg.norm(final - np.array([n, e, d])))
    else:
        # Tracking a moving reference: the flight controller's own figures
        # (from rotorpy's reported positions) are the measure; no bound.
        err = 0.0
    res["rotorpy"] = {
        "steps": len(track),
        "dt_s": a.dt,
        "final_ned_m": final.tolist(),
        "final_error_m": err,
        "max_altitude_m": float(-track[:, 3].min()),
    }
    text = json.dumps(res, indent=2)
    print(text)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text + "\n")
    if a.measure:
        src = "rotorpy_hil.py --measure " + a.measure
        if a.waypoint:
            record(f"rotorpy_{a.measure}_final_error_m", err, "m", src)
        if res.get("tracking_rmse_m") is not None:
            record(f"rotorpy_{a.measure}_rmse_m", res["tracking_rmse_m"], "m", src)
    ok = bool(np.all(np.isfinite(track))) and err <= a.max_final_error
    if a.scenario:
        rmse = res.get("tracking_rmse_m")
        ok = ok and rmse is not None and rmse <= a.max_rmse
    if not ok:
        print(f"FAIL: final error {err:.3f} m (bound {a.max_final_error} m), summary {res}", file=sys.stderr)
    what = f"tracking RMSE {res.get('tracking_rmse_m')} m" if a.scenario else f"final error {err:.3f} m"
    print(f"rotorpy check: {int(ok)} passed, {int(not ok)} failed ({what})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
