#!/usr/bin/env python3
"""Independent check of `sil-host mpc-step`: re-solves the printed QP
min ½zᵀHz + gᵀz, lb ≤ z ≤ ub in f64 with scipy (L-BFGS-B, tight tolerances,
then a KKT check of that reference) and compares the objective and solution
with what the firmware's f32 solver returned.

Usage: check_mpc_step.py PATH_TO_SIL_HOST
"""
import json
import subprocess
import sys

import numpy as np
from scipy.optimize import minimize

from measure import record


def reference(h, g, lb, ub):
    f = lambda z: 0.5 * z @ h @ z + g @ z
    jac = lambda z: h @ z + g
    z0 = np.clip(np.zeros_like(g), lb, ub)
    res = minimize(f, z0, jac=jac, method="L-BFGS-B", bounds=list(zip(lb, ub)),
                   options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 100000, "maxcor": 50})
    z = np.clip(res.x, lb, ub)
    # KKT of the reference: projected gradient ≈ 0.
    kkt = np.max(np.abs(z - np.clip(z - (h @ z + g), lb, ub)))
    return z, f(z), kkt


def check(exe, args):
    out = subprocess.run([exe, "mpc-step", *args, "--json"], check=True, capture_output=True, text=True).stdout
    d = json.loads(out)
    h, g = np.array(d["H"]), np.array(d["g"])
    lb, ub, z = np.array(d["lb"]), np.array(d["ub"]), np.array(d["solution"])
    zr, fr, kkt = reference(h, g, lb, ub)
    fz = 0.5 * z @ h @ z + g @ z
    rel = abs(fz - fr) / max(abs(fr), 1e-9)
    inside = bool(np.all(z >= lb) and np.all(z <= ub))
    width = np.max(ub - lb)
    dz = np.max(np.abs(z - zr)) / width
    # The solver's certificate is an upper bound on f(z) − f*: it must not
    # be below the gap to the independent f64 optimum (beyond the f32
    # rounding of the objective itself), and a solve that says it proved its
    # accuracy must be within it.
    rounding = 4 * np.finfo(np.float32).eps * max(abs(fr), 1.0)
    true_gap = fz - fr
    sound = d["gap"] + rounding >= true_gap
    proved = d["status"] in ("Exact", "Converged", "Polished", "BoundReached")
    within = (not proved) or true_gap <= d["certified_accuracy"]["objective"] + rounding
    ok = inside and rel <= 1e-5 and dz <= 1e-3 and sound and within
    print(f"mpc-step {' '.join(args):60s} objective {fz:12.4f} vs {fr:12.4f} (rel {rel:.1e}), "
          f"max|Δz|/width {dz:.1e}, in box {inside}, iterations {d['iterations']}/{d['iteration_bound']}, "
          f"{d['status']}, certified gap {d['gap']:.1e} vs true {true_gap:.1e}, "
          f"reference KKT {kkt:.1e} {'ok' if ok else 'MISMATCH'}")
    scale = max(abs(fr), 1.0)
    return ok, rel, d["gap"] / scale


def main():
    exe = sys.argv[1]
    cases = [
        ["--model", "euler", "--preset", "fast", "--scenario", "setpoint", "--at", "0.5"],
        ["--model", "quaternion", "--preset", "fast", "--scenario", "setpoint", "--at", "1.0", "--disturbance", "wind"],
        ["--model", "euler", "--preset", "fast", "--scenario", "helix", "--at", "30", "--disturbance", "wind,mismatch"],
        ["--model", "quaternion", "--preset", "fast", "--scenario", "circle", "--at", "7.3"],
        ["--model", "euler", "--preset", "thesis", "--scenario", "setpoint", "--at", "1.0"],
        ["--model", "quaternion", "--preset", "thesis", "--scenario", "helix", "--at", "12.5", "--disturbance", "wind"],
    ]
    runs = [check(exe, c) for c in cases]
    results = [r[0] for r in runs]
    src = "check_mpc_step.py"
    record("mpc_step_rel_objective_max_diff", max(r[1] for r in runs), "relative", src)
    # The certified gap relative to the objective (which reaches ~2e7 here).
    record("mpc_step_certified_gap_max_diff", max(r[2] for r in runs), "relative", src)
    passed = sum(results)
    print(f"mpc-step check: {passed} passed, {len(results) - passed} failed")
    sys.exit(0 if all(results) else 1)


if __name__ == "__main__":
    main()
