#!/usr/bin/env python3
"""Independent check of `sil-host design lqr` against python-control.

Linearises its own transcription of docs/book/src/model.md §4/§5 by central differences
(numpy), solves the LQR with python-control's `lqr` (SLICOT/scipy CARE), and
compares A, B and K with what the firmware core printed: the thesis' design
(continuous time, the OS4, Table 4.5 and 4.7's weights), and the designs the
flight controller flies (`design lqr --flown`): the project's weights (Table
4.5 with the pitch rate weighted 40; the quaternion form's derived from it),
the inputs weighted for each vehicle by its input ranges, discrete time at
the 2 ms control period (zero-order hold by scipy's matrix exponential,
`dlqr` with Q·ts, R·ts), on the OS4 and on rotorpy's Crazyflie and
Hummingbird (vehicles/*.toml).

Usage: check_design.py PATH_TO_SIL_HOST
"""
import json
import os
import subprocess
import sys
import tomllib

import control
import numpy as np
from scipy.linalg import expm

# The OS4 (docs/book/src/model.md §2); a vehicle file overrides these.
OS4 = {"mass_kg": 0.65, "gravity_mps2": 9.81, "inertia_kgm2": [7.5e-3, 7.5e-3, 1.3e-2], "arm_m": 0.23,
           "kf_ns2": 3.13e-5, "km_nms2": 7.5e-7, "kt_nspm": [0.1, 0.1, 0.15], "kr_nms": [0.1, 0.1, 0.15],
           "omega_max_radps": 600.0}
M, G = 0.65, 9.81
IX, IY, IZ = 7.5e-3, 7.5e-3, 1.3e-2
L, KF, KM = 0.23, 3.13e-5, 7.5e-7
KT = np.array([0.1, 0.1, 0.15])
KR = np.array([0.1, 0.1, 0.15])


def use(params):
    """Makes `params` the vehicle the model functions below describe."""
    global M, G, IX, IY, IZ, L, KF, KM, KT, KR
    M, G = params["mass_kg"], params["gravity_mps2"]
    IX, IY, IZ = params["inertia_kgm2"]
    L, KF, KM = params["arm_m"], params["kf_ns2"], params["km_nms2"]
    KT, KR = np.array(params["kt_nspm"]), np.array(params["kr_nms"])


def input_range(params):
    """The input box's upper ends from Ωmax (model §2): U1 ≤ 4 kf Ω², |U2|, |U3| ≤ kf Ω², |U4| ≤ 2 km Ω²."""
    w2 = params["omega_max_radps"] ** 2
    return np.array([4 * params["kf_ns2"] * w2, params["kf_ns2"] * w2, params["kf_ns2"] * w2,
                     2 * params["km_nms2"] * w2])


def rates(w, u):
    p, q, r = w
    return np.array([
        (L * u[1] - KR[0] * p + (IY - IZ) * q * r) / IX,
        (L * u[2] - KR[1] * q + (IZ - IX) * p * r) / IY,
        (u[3] - KR[2] * r + (IX - IY) * p * q) / IZ,
    ])


def euler_f(x, u):
    ph, th, ps = x[6:9]
    p, q, r = x[9:12]
    s, c, t = np.sin, np.cos, np.tan
    acc = np.array([
        -(KT[0] * x[3] + u[0] * (s(ph) * s(ps) + c(ph) * c(ps) * s(th))) / M,
        -(KT[1] * x[4] + u[0] * (c(ph) * s(ps) * s(th) - s(ph) * c(ps))) / M,
        -(KT[2] * x[5] - M * G + u[0] * c(ph) * c(th)) / M,
    ])
    att = np.array([p + q * s(ph) * t(th) + r * c(ph) * t(th), q * c(ph) - r * s(ph), (q * s(ph) + r * c(ph)) / c(th)])
    return np.concatenate([x[3:6], acc, att, rates(x[9:12], u)])


def quat_reduced_f(x, u):
    q1, q2, q3 = x[6:9]
    q0 = np.sqrt(1.0 - q1 * q1 - q2 * q2 - q3 * q3)
    p, q, r = x[9:12]
    acc = np.array([
        -(KT[0] * x[3] + u[0] * 2 * (q0 * q2 + q1 * q3)) / M,
        -(KT[1] * x[4] + u[0] * 2 * (q2 * q3 - q0 * q1)) / M,
        -(KT[2] * x[5] - M * G + u[0] * (1 - 2 * (q1 * q1 + q2 * q2))) / M,
    ])
    qd = 0.5 * np.array([p * q0 + r * q2 - q * q3, q * q0 - r * q1 + p * q3, r * q0 + q * q1 - p * q2])
    return np.concatenate([x[3:6], acc, qd, rates(x[9:12], u)])


def jacobians(f, x0, u0, h=1e-6):
    a = np.zeros((12, 12))
    b = np.zeros((12, 4))
    for j in range(12):
        e = np.zeros(12)
        e[j] = h
        a[:, j] = (f(x0 + e, u0) - f(x0 - e, u0)) / (2 * h)
    for j in range(4):
        e = np.zeros(4)
        e[j] = h
        b[:, j] = (f(x0, u0 + e) - f(x0, u0 - e)) / (2 * h)
    return a, b


def check(exe, model, yaw_deg):
    out = subprocess.run([exe, "design", "lqr", "--model", model, "--yaw-deg", str(yaw_deg), "--json"],
                         check=True, capture_output=True, text=True).stdout
    d = json.loads(out)
    yaw = np.radians(yaw_deg)
    x0 = np.zeros(12)
    u0 = np.array([M * G, 0.0, 0.0, 0.0])
    if model == "euler":
        x0[8] = yaw
        a, b = jacobians(euler_f, x0, u0)
        q = np.diag([10, 20, 90, 5, 5, 15, 10, 20, 35, 85, 5, 1.0])
        r = np.diag([1, 0.1, 0.1, 0.1])
    else:
        x0[8] = np.sin(yaw / 2)
        a, b = jacobians(quat_reduced_f, x0, u0)
        q, r = np.eye(12), np.eye(4)
    k, _, _ = control.lqr(a, b, q, r)
    errs = {
        "A": np.max(np.abs(np.array(d["A"]) - a)),
        "B": np.max(np.abs(np.array(d["B"]) - b)),
        "Q": np.max(np.abs(np.array(d["Q"]) - q)),
        "R": np.max(np.abs(np.array(d["R"]) - r)),
        "K": np.max(np.abs(np.array(d["K"]) - k)) / np.max(np.abs(k)),
    }
    ok = errs["A"] < 1e-6 and errs["B"] < 1e-6 and errs["Q"] == 0 and errs["R"] == 0 and errs["K"] < 1e-6
    print(f"design lqr {model:10s} yaw {yaw_deg:7.1f}°: max|ΔA| {errs['A']:.1e} max|ΔB| {errs['B']:.1e} "
          f"rel max|ΔK| {errs['K']:.1e} {'ok' if ok else 'MISMATCH'}")
    return ok


# The project's weights as the book states them (docs/book/src/controllers.md):
# Table 4.5 with the pitch rate weighted 40; the quaternion form's from them
# (x and y at their mean, the attitude ×4, as q ≈ angle / 2). R: Table 4.5's.
TUNED_Q = {
    "euler": [10, 20, 90, 5, 5, 15, 10, 20, 35, 85, 40, 1.0],
    "quaternion": [15, 15, 90, 5, 5, 15, 40, 80, 140, 85, 40, 1.0],
}
TUNED_R = [1, 0.1, 0.1, 0.1]


def check_flown(exe, model, yaw_deg, vehicle):
    cmd = [exe, "design", "lqr", "--model", model, "--yaw-deg", str(yaw_deg), "--flown"]
    params = dict(OS4)
    name = "OS4"
    if vehicle:
        cmd += ["--vehicle", vehicle]
        with open(vehicle, "rb") as f:
            params.update(tomllib.load(f))
        name = os.path.basename(vehicle)
    d = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    use(params)
    yaw = np.radians(yaw_deg) if model == "euler" else 0.0
    x0 = np.zeros(12)
    u0 = np.array([M * G, 0.0, 0.0, 0.0])
    if model == "euler":
        x0[8] = yaw
        a, b = jacobians(euler_f, x0, u0)
    else:
        a, b = jacobians(quat_reduced_f, x0, u0)
    q = np.diag(TUNED_Q[model])
    # The inputs' weights scaled by (the OS4's range / this vehicle's)²: a
    # unit of each input costs what the same share of its range did on the OS4.
    r = np.diag(np.array(TUNED_R) * (input_range(OS4) / input_range(params)) ** 2)
    ts = d["ts_s"]
    # Zero-order hold: expm([[A, B], [0, 0]] ts) = [[Ad, Bd], [0, I]].
    big = np.zeros((16, 16))
    big[:12, :12], big[:12, 12:] = a, b
    e = expm(big * ts)
    k, _, _ = control.dlqr(e[:12, :12], e[:12, 12:], q * ts, r * ts)
    errs = {
        "A": np.max(np.abs(np.array(d["A"]) - a)) / max(1.0, np.max(np.abs(a))),
        "B": np.max(np.abs(np.array(d["B"]) - b)) / np.max(np.abs(b)),
        "Q": np.max(np.abs(np.array(d["Q"]) - q)) / np.max(q),
        "R": np.max(np.abs(np.array(d["R"]) - r)) / np.max(r),
        "K": np.max(np.abs(np.array(d["K"]) - k)) / np.max(np.abs(k)),
    }
    ok = ts == 0.002 and all(v < 1e-6 for v in errs.values())
    print(f"design lqr --flown {model:10s} yaw {yaw_deg:6.1f}° {name:24s}: rel max|ΔA| {errs['A']:.1e} "
          f"|ΔB| {errs['B']:.1e} |ΔQ| {errs['Q']:.1e} |ΔR| {errs['R']:.1e} |ΔK| {errs['K']:.1e} "
          f"{'ok' if ok else 'MISMATCH'}")
    return ok


def main():
    exe = sys.argv[1]
    results = [check(exe, m, y) for m in ("euler", "quaternion") for y in (0.0, 15.0, 90.0, -120.0, 179.0)]
    use(OS4)
    here = os.path.dirname(os.path.abspath(__file__))
    vehicles = [None] + [os.path.join(here, "..", "vehicles", f"{v}-rotorpy.toml") for v in ("crazyflie", "hummingbird")]
    results += [check_flown(exe, m, y, v) for v in vehicles for (m, y) in
                (("euler", 0.0), ("euler", 90.0), ("euler", -120.0), ("quaternion", 0.0))]
    passed = sum(results)
    print(f"design check: {passed} passed, {len(results) - passed} failed")
    sys.exit(0 if all(results) else 1)


if __name__ == "__main__":
    main()
