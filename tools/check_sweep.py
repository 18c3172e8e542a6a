#!/usr/bin/env python3
"""Checks the robustness sweep behind the front page's figure: `sil-host
sweep` (400 vehicles drawn from seed 1, the helix for 30 s, both attitude
forms) flown by the controllers the project flies (PD, LQR, the fast MPC),
each a success (never diverged, never more than the tube from the
reference) on at least --min-success % of the vehicles.

    check_sweep.py target/sweep-400/sweep.json [--samples 400] [--min-success 99]

The thesis' own MPC preset (4 Hz) is reported, not held to it: the book's
sweep chapter says why it is not flown. Writes each flown controller's
success and worst RMSE to the measurements (tools/measure.py). Ends with
`sweep check: N passed, N failed`.
"""
import argparse
import json
import sys

from fctools.checks import Checks
from measure import record

FLOWN = ("PD", "LQR", "MPC fast")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sweep_json")
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--min-success", type=float, default=99.0, help="%")
    a = ap.parse_args()
    with open(a.sweep_json) as f:
        d = json.load(f)
    check = Checks("sweep")

    check(d["options"]["samples"] == a.samples, f"{d['options']['samples']} vehicles drawn (asked {a.samples})")
    rows = {r["controller"]: r for r in d["controllers"]}
    for c in FLOWN:
        for form in ("euler", "quaternion"):
            name = f"{c} {form}"
            r = rows.get(name)
            if r is None:
                check(False, f"{name}: no row")
                continue
            worst = r["rmse_percentiles_m"][3]
            check(r["success_pct"] >= a.min_success,
                  f"{name}: success {r['success_pct']:.1f} % (>= {a.min_success} %), worst RMSE {worst:.3f} m")
    # Every row's figures, the thesis preset's too (not held to the
    # threshold: the book states what it does).
    for name, r in rows.items():
        key = "sweep_" + name.lower().replace(" ", "_")
        record(key + "_success_pct", r["success_pct"], "%", "check_sweep.py")
        for p, v in zip(("p50", "p90", "p99", "max"), r["rmse_percentiles_m"]):
            record(f"{key}_rmse_{p}_m", v, "m", "check_sweep.py")
    fast = [rows[f"MPC fast {f}"] for f in ("euler", "quaternion") if f"MPC fast {f}" in rows]
    if fast:
        record("sweep_mpc_fast_success_pct_min", min(r["success_pct"] for r in fast), "%", "check_sweep.py")
        record("sweep_mpc_fast_rmse_max_m", max(r["rmse_percentiles_m"][3] for r in fast), "m", "check_sweep.py")
    record("sweep_samples", d["options"]["samples"], "vehicles", "check_sweep.py")
    print(check.summary())
    sys.exit(check.exit_code())


if __name__ == "__main__":
    main()
