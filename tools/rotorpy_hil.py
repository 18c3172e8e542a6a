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
measurements of the flight from rotorpy's true state added under "rotorpy"
(the flight controller's own figures come from the positions rotorpy
reports, quantised to the millimetre): for waypoints, the worst distance to
the last one over a window (--hold-from to the end) and the final one; for
a scenario, the RMSE, worst and final distance to its reference from
--scenario-start on. Exits non-zero if the vehicle diverged, strayed more
than --max-hold-error from the last waypoint in the window, or tracked with
an RMSE above --max-rmse.
"""
import argparse
import importlib.metadata
import json
import os
import platform
import re
import socket
import subprocess
import sys
import tempfile

# pymavlink speaks MAVLink 1 unless told otherwise before it is imported;
# the flight controller reads MAVLink 2 only.
os.environ["MAVLINK20"] = "1"

import numpy as np
from rotorpy.controllers.quadrotor_control import SE3Control
from rotorpy.vehicles.crazyflie_params import quad_params as crazyflie_params
from rotorpy.vehicles.hummingbird_params import quad_params as hummingbird_params
from rotorpy.vehicles.multirotor import Multirotor
from rotorpy.vehicles.px4_multirotor import PX4Multirotor
from rotorpy.wind.default_winds import ConstantWind
from scipy.spatial.transform import Rotation

from children import EndsWithFlight
from fctools.image_log import stack, timing
from fctools.lossy import LossyLink
from fctools.lossy import parse as lossy_parse
from fctools.pieces import Pieces, cflib_figure8, read_csv, write_csv
from measure import budgets, record
from reference import EIGHT_PERIOD_S, START_NED_M, Reference, window_figures

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


def integrator(dt):
    """How rotorpy integrates its vehicle over each step of `dt` s, ours and
    the peer's alike: scipy's RK45 (rotorpy's `Multirotor` default) with
    `PX4Multirotor`'s tolerances (rtol 1e-3, atol 1e-6), the first step the
    step asked for. `PX4Multirotor` itself asks for Radau, which estimates
    its Jacobian by finite differences at every step (33 evaluations of the
    dynamics a 2 ms step where RK45 takes 7): `test.sh`'s 30 flights take
    752 s instead of 2355 s. The LQR's step flight moves by 2e-5 m or less
    (its worst hold 9.437 -> 9.453 mm, final 2.935 -> 2.944 mm), three
    orders below its bound; the fast MPC's final error, one instant of its
    mm-sized wander, by 2.8 mm (1.7 -> 4.5 mm)."""
    return {"method": "RK45", "rtol": 1e-3, "atol": 1e-6, "max_step": 0.01, "first_step": dt}


class Lockstep(PX4Multirotor):
    """rotorpy's vehicle, waiting as long as it takes for the flight
    controller's answer (its own waits 10 ms of wall time and then flies
    with the motors off: a flight controller in an emulator is slower)."""

    commanded = np.zeros(4)
    # --state truth: rotorpy's true state as an ODOMETRY before each step's
    # HIL messages, which the flight controller flies instead of its estimate.
    send_truth = False

    def _send_hil_state_quaternion(self, state, statedot):
        if self.send_truth:
            self.conn.mav.odometry_send(*odometry(state, self.t))
        super()._send_hil_state_quaternion(state, statedot)

    def _fetch_latest_px4_control(self, blocking=True):
        msg = self.conn.recv_match(type="HIL_ACTUATOR_CONTROLS", blocking=True, timeout=30.0)
        if msg is None:
            raise RuntimeError("no HIL_ACTUATOR_CONTROLS from the flight controller in 30 s")
        self.commanded = np.array(msg.controls[: self.num_rotors], dtype=float)
        return {"cmd_motor_speeds": [c * self.rotor_speed_max for c in msg.controls[: self.num_rotors]]}


class Peer:
    """rotorpy's own SE3 geometric controller (`SE3Control`, the
    Lee/Mellinger family) flying rotorpy's vehicle from its true state, at
    every step of `dt` (500 Hz at the default 2 ms): the peer our flight
    controller is measured against, on the same vehicle, reference, wind and
    windows. It starts where ours does, on the ground at home facing east
    (rotorpy's yaw 0), and holds that heading."""

    def __init__(self, quad_params, reference, dt):
        # The same integrator as our flights' (`integrator`): SE3 from the
        # true state brings the vehicle to rest to 1e-13 m/s, where scipy's
        # own first-step guess shrinks to microseconds and a 30 s hold takes
        # minutes; the first step is the step asked for.
        self.vehicle = Multirotor(quad_params, initial_state=PX4Multirotor_initial(quad_params), aero=True,
                                  enable_ground=True, integrator_kwargs=integrator(dt))
        self.initial_state = dict(self.vehicle.initial_state)
        self.controller = SE3Control(quad_params)
        self.reference = reference
        self.rotor_speed_max = quad_params["rotor_speed_max"]
        self.commanded = np.zeros(4)

    def step(self, state, t, dt):
        pos, vel, acc, jerk, snap = self.reference.at(t)
        enu = lambda v: np.array([v[1], v[0], -v[2]])
        yaw, yaw_dot = self.reference.yaw_enu(t)
        flat = {"x": enu(pos), "x_dot": enu(vel), "x_ddot": enu(acc), "x_dddot": enu(jerk), "x_ddddot": enu(snap),
                "yaw": yaw, "yaw_dot": yaw_dot, "yaw_ddot": 0.0}
        control = self.controller.update(t, state, flat)
        self.commanded = np.asarray(control["cmd_motor_speeds"], dtype=float) / self.rotor_speed_max
        return self.vehicle.step(state, control, dt)


# The frames odometry() turns rotorpy's state between, made once (it runs
# at every step).
NED_OF_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FLU_OF_FRD = np.diag([1.0, -1.0, -1.0])
UNKNOWN_COVARIANCE = [float("nan")] * 21


def odometry(state, t):
    """rotorpy's true state (ENU world, FLU body, its quaternion x, y, z, w)
    as MAVLink ODOMETRY's arguments: position in MAV_FRAME_LOCAL_NED about
    the start (rotorpy's origin, where PX4Multirotor starts: home), the
    attitude body FRD -> NED (w, x, y, z), velocity and rates in
    MAV_FRAME_BODY_FRD; covariances unknown (NaN)."""
    ned_of_enu, flu_of_frd = NED_OF_ENU, FLU_OF_FRD
    r = ned_of_enu @ Rotation.from_quat(state["q"]).as_matrix() @ flu_of_frd  # FRD -> NED
    x, y, z, w = Rotation.from_matrix(r).as_quat()
    pos = ned_of_enu @ np.asarray(state["x"], dtype=float)
    vel = r.T @ (ned_of_enu @ np.asarray(state["v"], dtype=float))
    rates = flu_of_frd @ np.asarray(state["w"], dtype=float)
    return (round(t * 1e6), 1, 12, *map(float, pos), [float(w), float(x), float(y), float(z)],
            *map(float, vel), *map(float, rates), UNKNOWN_COVARIANCE, UNKNOWN_COVARIANCE, 0, 0, 100)


def PX4Multirotor_initial(quad_params):
    """PX4Multirotor's own start: at home, at rest, rotors stopped."""
    return {"x": np.zeros(3), "v": np.zeros(3), "q": np.array([0, 0, 0, 1]), "w": np.zeros(3),
            "wind": np.zeros(3), "rotor_speeds": np.zeros(quad_params["num_rotors"])}


def hover_fraction(q):
    """The rotor speed that holds `q`'s weight, as a fraction of its maximum."""
    return float(np.sqrt(q["mass"] * 9.81 / (q["num_rotors"] * q["k_eta"])) / q["rotor_speed_max"])


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
    ap.add_argument("--controller", default="lqr",
                    help="pd | lqr | mpc: ours (sil-host px4-hil); se3: rotorpy's SE3Control from its true "
                         "state, the peer (no sil-host)")
    ap.add_argument("--target", default="in-process", help="in-process | qemu (the firmware-mavlink image)")
    ap.add_argument("--waypoint", action="append", help="T,N,E,D (NED about the start, m)")
    ap.add_argument("--scenario", help="circle | eight | helix: its trajectory from --scenario-start s (RMSE "
                                       "reported from then, the eight's from the end of its first lap)")
    ap.add_argument("--scenario-start", type=float, default=3.0)
    ap.add_argument("--trajectory", metavar="CSV|cflib:figure8",
                    help="a Crazyflie trajectory file (or the figure-8 of cflib's "
                         "autonomous_sequence_high_level.py, from its pinned sdist), handed to the vehicle as if "
                         "uploaded (sil-host px4-hil --trajectory): it hovers 1 m above home heading north and "
                         "flies it from there at --trajectory-start s; measured over the whole of it")
    ap.add_argument("--trajectory-start", type=float, default=5.0)
    ap.add_argument("--no-preview", action="store_true",
                    help="sil-host px4-hil --no-preview: the controller extrapolates each step's set-point")
    ap.add_argument("--duration", type=float, default=12.0, help="simulated seconds")
    ap.add_argument("--dt", type=float, default=0.002, help="rotorpy's step, s")
    ap.add_argument("--port", type=int, default=4560)
    ap.add_argument("--max-hold-error", type=float, default=0.05,
                    help="m: the worst distance to the last waypoint from --hold-from on (rotorpy's truth)")
    ap.add_argument("--hold-from", type=float,
                    help="s: the hold window's start (default: the last waypoint's time + 5 s, at most "
                         "1 s before the end)")
    ap.add_argument("--max-rmse", type=float, default=0.15, help="m (scenario tracking, 3-D)")
    ap.add_argument("--max-whole", metavar="RMSE,WORST",
                    help="m: the whole window's RMSE and worst distance must not exceed these")
    ap.add_argument("--beat", metavar="JSON",
                    help="another flight's summary (--json): this flight's RMSE over each window both have "
                         "(whole and steady) must not exceed that flight's, nor its step's settling time "
                         "(tools/beat.py)")
    ap.add_argument("--state", choices=("estimate", "truth"), default="estimate",
                    help="what our controller flies: its estimator's state (the whole flight controller) "
                         "or rotorpy's true state, sent as ODOMETRY (the controller alone, as SE3 flies)")
    ap.add_argument("--csv", help="the flight controller's trace")
    ap.add_argument("--ulog", help="the flight as a ULog (sil-host px4-hil --ulog)")
    ap.add_argument("--json", help="write the summary here too")
    ap.add_argument("--measure", metavar="NAME",
                    help="write the flight's figures to the measurements (tools/measure.py) as rotorpy_NAME_*")
    ap.add_argument("--seed", type=int, default=1, help="seeds rotorpy's IMU noise (numpy)")
    ap.add_argument("--wind", metavar="N,E,D",
                    help="a steady wind, m/s NED (rotorpy's ConstantWind, the air's velocity over the ground)")
    ap.add_argument("--gcs", action="store_true",
                    help="no mission: tools/mav_gcs.py (a pymavlink ground station on UDP 14550) "
                         "sets parameters, arms and flies the vehicle; the flight ends when it is done")
    ap.add_argument("--signing", action="store_true",
                    help="like --gcs, with tools/mav_signing.py: an owner provisions a MAVLink signing key "
                         "and flies signed while an intruder's unsigned, wrongly signed and replayed frames "
                         "must be ignored")
    ap.add_argument("--storage", metavar="FILE",
                    help="sil-host px4-hil --storage FILE; with --signing the owner then sets a key and a "
                         "parameter to keep (noted in FILE.json)")
    ap.add_argument("--restart", action="store_true",
                    help="with --signing and --storage: only check that the key, its timestamps and the "
                         "parameter survived the restart")
    ap.add_argument("--cut", action="store_true",
                    help="with --signing and --storage: the owner arms, takes off and, in flight, notes the "
                         "vehicle's last signature timestamp; then the flight controller is killed (SIGKILL), "
                         "as a power cut would stop it. A --restart run after it checks the timestamps go on")
    ap.add_argument("--gcs-port", type=int, default=14550)
    ap.add_argument("--lossy", metavar="SPEC",
                    help="the ground station's link through tools/fctools/lossy.py (e.g. drop=0.1,burst=0.5@10,"
                         "dup=0.02,delay=0.2,seed=1): the vehicle sends to --gcs-port + 1")
    ap.add_argument("--mavsdk", action="store_true",
                    help="like --gcs, with tools/mavsdk_flight.py (MAVSDK, PyPI) as the ground station; "
                         "rotorpy's position is sent to it on UDP --truth-port")
    ap.add_argument("--mavsdk-failure", metavar="TABLE",
                    help="like --mavsdk, with tools/mavsdk_failure.py (MAVSDK's Failure plugin) injecting sensor "
                         "faults in flight; the faults' rows to TABLE (JSON)")
    ap.add_argument("--faults", metavar="FAULT,...",
                    help="with --mavsdk-failure: these faults only (tools/mavsdk_failure.py --only)")
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
    if (bool(a.waypoint) + bool(a.scenario) + bool(a.trajectory) + a.gcs + a.signing + a.mavsdk + a.mavproxy
            + bool(a.mavsdk_failure)) != 1:
        ap.error("give --waypoint(s), --scenario, --trajectory, --gcs, --signing, --mavsdk, --mavsdk-failure "
                 "or --mavproxy")
    gcs = None
    truth_sock = None
    here = os.path.dirname(__file__)
    if a.gcs or a.signing or a.mavsdk or a.mavproxy or a.mavsdk_failure:
        # The ground station listens first, as QGroundControl does.
        if a.mavsdk or a.mavproxy or a.mavsdk_failure:
            # MAVSDK's URL and MAVProxy's (pymavlink's) spell UDP differently.
            name, url = (("mavsdk_flight.py", f"udpin://127.0.0.1:{a.gcs_port}") if a.mavsdk
                         else ("mavsdk_failure.py", f"udpin://127.0.0.1:{a.gcs_port}") if a.mavsdk_failure
                         else ("mavproxy_session.py", f"udpin:127.0.0.1:{a.gcs_port}"))
            script = [os.path.join(here, name), "--url", url, "--truth-port", str(a.truth_port)]
            if a.mavsdk_failure:
                script += ["--table", a.mavsdk_failure]
                if a.faults:
                    script += ["--only", a.faults]
                if a.target == "qemu":
                    script += ["--tag", "fault_qemu"]  # the image's figures beside the SIL's
            if a.mavsdk and a.lossy:
                # The lossy link's transfers, counted as mavsdk[_qemu]_lossy_<drop %>_transfers_*.
                where = "_qemu" if a.target == "qemu" else ""
                script += ["--lossy", "--transfers",
                           f"mavsdk{where}_lossy_{round(100 * lossy_parse(a.lossy)['drop'])}"]
            if a.target == "qemu":
                # The image in QEMU flies about 5x slower than real time.
                script += ["--timeout", "180"]
            truth_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        else:
            name = "mav_signing.py" if a.signing else "mav_gcs.py"
            script = [os.path.join(here, name), "--url", f"udpin:127.0.0.1:{a.gcs_port}"]
            if a.signing and a.storage:
                script += ["--after-restart" if a.restart else "--cut" if a.cut else "--keep",
                           a.storage + ".json"]
        gcs = subprocess.Popen([sys.executable] + script, stdout=subprocess.PIPE, text=True)
        vehicle_port = a.gcs_port
        if a.lossy:
            vehicle_port = a.gcs_port + 1
            lossy = LossyLink(vehicle_port, ("127.0.0.1", a.gcs_port), a.lossy)
            lossy.start()
        cmd += ["--gcs", f"127.0.0.1:{vehicle_port}", "--gcs-only"]
    for w in a.waypoint or []:
        cmd += ["--waypoint", w]
    for p in a.param or []:
        cmd += ["--param", p]
    if a.scenario:
        cmd += ["--scenario", a.scenario, "--scenario-start", str(a.scenario_start)]
    pieces = None
    if a.trajectory:
        rows = cflib_figure8() if a.trajectory == "cflib:figure8" else read_csv(a.trajectory)
        path = os.path.join(tempfile.mkdtemp(prefix="rotorpy-traj-"), "trajectory.csv")
        write_csv(rows, path)
        pieces = Pieces(rows, START_NED_M)
        cmd += ["--trajectory", path, "--trajectory-start", str(a.trajectory_start)]
    if a.no_preview:
        cmd += ["--no-preview"]
    # The flight controller's trace (time, reported, estimated and set-point
    # NED): its set-points are the reference rotorpy's truth is measured to.
    csv_path = a.csv or os.path.join(tempfile.mkdtemp(prefix="rotorpy-hil-"), "trace.csv")
    cmd += ["--csv", csv_path]
    if a.ulog:
        cmd += ["--ulog", a.ulog]
    if a.storage:
        cmd += ["--storage", a.storage]
    if a.state == "truth":
        cmd += ["--state", "truth"]
    np.random.seed(a.seed)
    waypoints = [tuple(float(v) for v in w.split(",")) for w in a.waypoint or []]
    reference = None
    if pieces is not None:
        reference = Reference(pieces=pieces, start_s=a.trajectory_start)
    elif waypoints or a.scenario in ("circle", "eight"):
        reference = Reference(waypoints=waypoints, kind=a.scenario, start_s=a.scenario_start)
    peer = a.controller == "se3"
    if peer:
        if reference is None or gcs is not None:
            ap.error("--controller se3 flies --waypoint(s), --scenario circle|eight or --trajectory")
        vehicle = Peer(params_for(a.vehicle, "rotorpy"), reference, a.dt)
    else:
        fc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True)
        fc_watch = EndsWithFlight(fc, "sil-host px4-hil", others=[gcs])
        vehicle = Lockstep(params_for(a.vehicle, a.layout), mavlink_url=f"tcpin:localhost:{a.port}",
                           integrator_kwargs=integrator(a.dt))
        vehicle.send_truth = a.state == "truth"
    state = dict(vehicle.initial_state)
    wind = None
    if a.wind:
        wn, we, wd = (float(v) for v in a.wind.split(","))
        wind = ConstantWind(we, wn, -wd)  # rotorpy's world frame is ENU
    zero = {"cmd_motor_speeds": np.zeros(4)}
    track, commands, rotors = [], [], []
    # rotorpy's own parameters: the speeds the figures are fractions of.
    rotorpy_q = params_for(a.vehicle, "rotorpy")
    omega_max = rotorpy_q["rotor_speed_max"]
    steps = round(a.duration / a.dt)
    for k in range(steps):
        if wind is not None:
            state["wind"] = wind.update(k * a.dt, state["x"])
        state = vehicle.step(state, k * a.dt, a.dt) if peer else vehicle.step(state, zero, a.dt)
        commands.append(vehicle.commanded)
        rotors.append(np.asarray(state["rotor_speeds"], dtype=float) / omega_max)
        x = np.asarray(state["x"], dtype=float)  # ENU
        track.append([k * a.dt, x[1], x[0], -x[2]])  # t, north, east, down
        if truth_sock is not None and k % 10 == 0:
            msg = json.dumps({"t": k * a.dt, "ned": track[-1][1:]}).encode()
            truth_sock.sendto(msg, ("127.0.0.1", a.truth_port))
        if not np.all(np.isfinite(x)) or np.abs(x).max() > 100:
            break
        if gcs is not None and k % 50 == 0 and gcs.poll() is not None:
            break
    if peer:
        out = json.dumps({"controller": "se3", "target": "rotorpy (true state)", "steps": len(track)})
    elif a.cut:
        # A power cut: the flight controller stops where it is, armed and in
        # the air, with no summary and nothing stored on the way out.
        fc_watch.done()
        fc.kill()
        fc.communicate(timeout=60)
        vehicle.conn.close()
        out = json.dumps({"controller": a.controller, "target": "in-process", "steps": len(track),
                          "end": "killed (SIGKILL) in flight, as a power cut"})
    else:
        # Hanging up ends the flight controller's session (and its summary).
        fc_watch.done()
        vehicle.conn.close()
        out, _ = fc.communicate(timeout=60)
        if fc.returncode != 0:
            print(f"sil-host px4-hil failed ({fc.returncode})", file=sys.stderr)
            return 1
    res = json.loads(out)
    res.setdefault("controller", a.controller)
    res["versions"] = versions()
    track = np.array(track)
    if gcs is not None:
        if gcs.poll() is None:
            gcs.kill()
        gcs_out, _ = gcs.communicate(timeout=60)
        sys.stderr.write(gcs_out)
        prefix = ("mavsdk check:" if a.mavsdk else "fault check:" if a.mavsdk_failure
                  else "mavproxy check:" if a.mavproxy
                  else "signing check:" if a.signing else "gcs check:")
        line = [ln for ln in gcs_out.splitlines() if ln.startswith(prefix)]
        res["gcs"] = line[-1] if line else f"{prefix} 0 passed, 1 failed (the ground station did not finish)"
        if a.lossy:
            lossy.stop()
            res["lossy_link"] = {"spec": a.lossy, **lossy.counts}
            print(f"lossy link ({a.lossy}): {lossy.counts}", file=sys.stderr)
        def also(ok, what):
            """One more check on the ground station's line (it counts)."""
            print(("ok   " if ok else "FAIL ") + what, file=sys.stderr)
            p, f = (int(v) for v in re.match(r".*: (\d+) passed, (\d+) failed", res["gcs"]).groups())
            res["gcs"] = f"{prefix} {p + bool(ok)} passed, {f + (not ok)} failed" + res["gcs"].split(" failed", 1)[1]
            return ok

        if a.mavproxy and line:
            # MAVProxy set a key: the flight controller's own count says its
            # frames then came signed, and none were dropped.
            ok = res.get("signing_on") and res.get("signing_accepted", 0) > 0 and not any(res["signing_dropped"])
            line = line if also(ok, f"the vehicle accepted {res.get('signing_accepted')} signed frames from "
                                    f"MAVProxy, dropped {res.get('signing_dropped')}") else []
        if a.signing and a.target == "qemu" and line:
            # The image names what keeps its settings (QEMU models no flash).
            said = [ln for ln in res.get("firmware_log", []) if "storage:" in ln]
            ok = any("RAM stand-in" in ln for ln in said)
            line = line if also(ok, f"the image names what keeps its settings: {said[:1]}") else []
        if a.target == "qemu" and line:
            # The image paints its stack at boot, logs the boot's mark, paints it
            # again and logs the tasks' mark (every task's frames, nested) every
            # 1000 steps when it has grown (fc_stm32f405::stack).
            boot, tasks, capacity = stack(res.get("firmware_log", []))
            budget = budgets()["budget_image_stack_bytes"]
            line = line if also(0 < boot <= budget and 0 < tasks <= budget,
                                f"the image's stack reached {boot} B at boot and {tasks} B in its tasks, "
                                f"of the {capacity} B it may grow to (budget {budget} B)") else []
            # Every step, data-ready (its HIL_SENSOR frame whole) to its end
            # (the motors, the simulator's answer and the telemetry due
            # written), within the image step's budget: one 1 kHz period at
            # CPI 1.5 with a 1.5 margin (fc_stm32f405::timing, logged every
            # 1000 steps and at once when one is late).
            t = timing(res.get("firmware_log", []))
            step_budget = budgets()["budget_image_step_instructions"]
            ok = (t is not None and t["steps"] >= 1000 and t["missed"] == 0 and t["imu"] == 0
                  and t["answer"] <= step_budget)
            line = line if also(ok, (f"the image answered every step within the 1 kHz budget: {t['missed']} late "
                                     f"of {t['steps']}, worst data-ready -> step's end {t['answer']} instructions "
                                     f"(estimate {t['estimate']}; budget {step_budget}: 168 000 cycles at CPI "
                                     f"1.5 x 1.5)") if t else "the image logged its steps' timing") else []
            if a.mavsdk:
                src = "tools/rotorpy_hil.py --target qemu --mavsdk"
                record("mavlink_qemu_stack_boot_bytes", boot, "bytes", src)
                record("mavlink_qemu_stack_tasks_bytes", tasks, "bytes", src)
            flight = "mavsdk" if a.mavsdk else "mavsdk-failure" if a.mavsdk_failure else "signing" if a.signing else None
            if t and flight:
                tag = {"mavsdk": "mavlink_qemu", "mavsdk-failure": "mavlink_qemu_faults",
                       "signing": "mavlink_qemu_signing"}[flight]
                src = f"tools/rotorpy_hil.py --target qemu --{flight}"
                record(f"{tag}_step_worst_icount", t["answer"], "instructions", src)
                record(f"{tag}_late_steps", t["missed"], "steps", src)
        text = json.dumps(res, indent=2)
        print(text)
        if a.json:
            with open(a.json, "w") as f:
                f.write(text + "\n")
        print(res["gcs"])
        return 0 if gcs.returncode == 0 and line else 1
    final = track[-1, 1:4]
    res["rotorpy"] = {
        "steps": len(track),
        "dt_s": a.dt,
        "final_ned_m": final.tolist(),
        "max_altitude_m": float(-track[:, 3].min()),
        "wind_ned_mps": [float(v) for v in a.wind.split(",")] if a.wind else [0.0, 0.0, 0.0],
    }
    end_s = float(track[-1, 0])
    if a.waypoint:
        t_goal, n, e, d = (float(v) for v in a.waypoint[-1].split(","))
        goal = np.array([n, e, d])
        hold_from = a.hold_from if a.hold_from is not None else min(t_goal + 5.0, end_s - 1.0)
        dist = np.linalg.norm(track[:, 1:4] - goal, axis=1)
        window = track[:, 0] >= hold_from
        err = float(np.linalg.norm(final - goal))
        hold = float(dist[window].max()) if window.any() else float("inf")
        res["rotorpy"].update(final_error_m=err, hold_window_s=[hold_from, end_s], hold_worst_m=hold)
    else:
        # Tracking a moving reference: rotorpy's truth against the set-point
        # the flight controller flew at each of its trace's rows (50 Hz); the
        # peer's, at each step.
        # The eight's first lap is its entry: its error counts from the end
        # of that lap (sil-host's Scenario::tracking_from_s).
        from_s = a.scenario_start + (EIGHT_PERIOD_S if a.scenario == "eight" else 0.0)
        if pieces is not None:
            from_s = a.trajectory_start
        if peer:
            # The peer's reference at each of rotorpy's steps.
            t_rows = track[:, 0][track[:, 0] >= from_s]
            sp = np.array([reference.at(t)[0] for t in t_rows])
        else:
            trace = np.genfromtxt(csv_path, delimiter=",", names=True)
            rows = trace[(trace["t"] >= from_s) & np.isfinite(trace["sp_north"])]
            t_rows = rows["t"]
            sp = np.stack([rows["sp_north"], rows["sp_east"], rows["sp_down"]], axis=1)
            if reference is not None and len(t_rows):
                # The peer's reference is the one ours flew (to float noise).
                mine = np.array([reference.at(t)[0] for t in t_rows])
                res["rotorpy"]["reference_mismatch_m"] = float(np.abs(mine - sp).max())
        k = np.clip(np.rint(t_rows / a.dt).astype(int), 0, len(track) - 1)
        dist = np.linalg.norm(track[k, 1:4] - sp, axis=1)
        err = float(dist[-1]) if len(dist) else float("inf")
        res["rotorpy"].update(
            window_s=[from_s, end_s], rmse_m=float(np.sqrt(np.mean(dist**2))) if len(dist) else None,
            worst_m=float(dist.max()) if len(dist) else None, final_error_m=err, rows=len(dist))
    if reference is not None:
        hover = hover_fraction(rotorpy_q)
        res["rotorpy"]["hover_rotor"] = hover
        res["rotorpy"]["windows"] = window_figures(reference, track, np.array(commands), hover, end_s,
                                                     np.array(rotors))
    text = json.dumps(res, indent=2)
    print(text)
    if a.json:
        with open(a.json, "w") as f:
            f.write(text + "\n")
    r = res["rotorpy"]
    if a.measure:
        src = "rotorpy_hil.py --measure " + a.measure
        record(f"rotorpy_{a.measure}_final_error_m", r["final_error_m"], "m", src)
        if a.waypoint:
            record(f"rotorpy_{a.measure}_hold_worst_m", r["hold_worst_m"], "m", src)
        elif r["rmse_m"] is not None:
            record(f"rotorpy_{a.measure}_rmse_m", r["rmse_m"], "m", src)
            record(f"rotorpy_{a.measure}_worst_m", r["worst_m"], "m", src)
        if res.get("max_estimate_error_m") is not None:
            record(f"rotorpy_{a.measure}_estimate_error_max_m", res["max_estimate_error_m"], "m", src)
        # The peer table's figures (tools/peer_table.py).
        if "hover_rotor" in r:
            record(f"rotorpy_{a.measure}_hover_rotor", r["hover_rotor"], "fraction of the maximum rotor speed", src)
        for name, w in r.get("windows", {}).items():
            if name == "settling_s":
                if w is not None:
                    record(f"rotorpy_{a.measure}_settling_s", w, "s", src)
                continue
            for fig in ("rmse_m", "worst_m", "final_m"):
                record(f"rotorpy_{a.measure}_{name}_{fig}", w[fig], "m", src)
            record(f"rotorpy_{a.measure}_{name}_effort", w["effort"], "fraction of the maximum rotor speed", src)
            record(f"rotorpy_{a.measure}_{name}_peak_rotor", w["peak_rotor"], "fraction of the maximum rotor speed",
                   src)
    ok = bool(np.all(np.isfinite(track)))
    if a.beat:
        from beat import beat
        with open(a.beat) as f:
            other = json.load(f)
        # A trajectory's whole window is the trajectory; a scenario's
        # whole span and steady laps, a step's settling too.
        windows = ("whole",) if pieces is not None else ("whole", "steady")
        for beats, line in beat(r, other["rotorpy"], a.controller, other.get("controller", a.beat), windows):
            ok = ok and beats
            print(line)
    if a.max_whole:
        bound_rmse, bound_worst = (float(v) for v in a.max_whole.split(","))
        w = r["windows"]["whole"]
        within = w["rmse_m"] <= bound_rmse and w["worst_m"] <= bound_worst
        ok = ok and within
        print(f"rotorpy check: {int(within)} passed, {int(not within)} failed ({a.controller} "
              f"{100 * w['rmse_m']:.2f} cm RMSE, worst {100 * w['worst_m']:.2f} cm over {w['window_s'][0]:g}-"
              f"{w['window_s'][1]:.2f} s, bounds {100 * bound_rmse:.2f} and {100 * bound_worst:.2f} cm, "
              f"rotorpy's truth)")
    mismatch = r.get("reference_mismatch_m", 0.0)
    if mismatch > 1e-3:
        ok = False
        print(f"FAIL: the flight controller's set-points left the reference by {mismatch:.4f} m", file=sys.stderr)
    if a.waypoint:
        ok = ok and r["hold_worst_m"] <= a.max_hold_error
        what = (f"worst {100 * r['hold_worst_m']:.1f} cm from the goal over {r['hold_window_s'][0]:.0f}-"
                f"{r['hold_window_s'][1]:.0f} s (bound {100 * a.max_hold_error:.1f} cm), final "
                f"{100 * r['final_error_m']:.1f} cm")
    else:
        ok = ok and r["rmse_m"] is not None and r["rmse_m"] <= a.max_rmse
        what = (f"tracking RMSE {r['rmse_m']:.4f} m (bound {a.max_rmse:.4f} m), worst {r['worst_m']:.3f} m, "
                f"final {r['final_error_m']:.3f} m from {r['window_s'][0]:g} s, rotorpy's truth")
    if not ok:
        print(f"FAIL: {what}; summary {res}", file=sys.stderr)
    print(f"rotorpy check: {int(ok)} passed, {int(not ok)} failed ({what})")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
