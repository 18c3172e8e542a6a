#!/usr/bin/env python3
"""Independent check of `sil-host design lqr` against python-control.

Linearises its own transcription of docs/book/src/model.md §4/§5 by central differences
(numpy), solves the LQR with python-control's `lqr` (SLICOT/scipy CARE), and
compares A, B and K with what the firmware core printed.

Usage: check_design.py PATH_TO_SIL_HOST
"""
import json
import subprocess
import sys

import control
import numpy as np

M, G = 0.65, 9.81
IX, IY, IZ = 7.5e-3, 7.5e-3, 1.3e-2
L, KF, KM = 0.23, 3.13e-5, 7.5e-7
KT = np.array([0.1, 0.1, 0.15])
KR = np.array([0.1, 0.1, 0.15])


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


def main():
    exe = sys.argv[1]
    results = [check(exe, m, y) for m in ("euler", "quaternion") for y in (0.0, 15.0, 90.0, -120.0, 179.0)]
    passed = sum(results)
    print(f"design check: {passed} passed, {len(results) - passed} failed")
    sys.exit(0 if all(results) else 1)


if __name__ == "__main__":
    main()
