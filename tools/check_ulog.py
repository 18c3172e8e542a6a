#!/usr/bin/env python3
"""Reads sil-host's ULog flight logs back with pyulog (PX4's own reader, PyPI)
and checks them against the flight's JSON summary.

    check_ulog.py fly SIL_HOST          flies `sil-host fly … --ulog --json` itself
    check_ulog.py hil FLIGHT.ulg FLIGHT.json
                                        a `sil-host px4-hil --ulog` flight
                                        (tools/rotorpy_hil.py --ulog --json)

`fly`: the per-axis RMSE and the final error recomputed from the log's
ground truth and set-point equal the JSON's (the log holds f32: 1e-5
relative), every parameter of the table is there with the flight's vehicle
and controller, the estimate is logged and close to the truth. `hil`: the
log's last true position is the JSON's `final_pos_ned_m`, its first armed
`vehicle_status` is `armed_at_s`, its logged messages are the vehicle's
STATUSTEXTs in order, its largest armed estimate error is
`max_estimate_error_m` (to one simulator step), and the motors stay in
[0, 1]. Ends with `ulog check: N passed, N failed`.
"""
import json
import math
import subprocess
import sys
import tempfile

import numpy as np
from pyulog import ULog

from fctools.checks import Checks
from fctools.params import table_length

check = Checks("ulog")


def topic(log, name):
    ds = [d for d in log.data_list if d.name == name]
    if not ds:
        raise SystemExit(f"ulog check: no topic {name} in the log")
    return ds[0].data


def close(a, b, rel=1e-5, abs_=1e-6):
    return abs(a - b) <= abs_ + rel * abs(b)


def check_fly(sil):
    with tempfile.TemporaryDirectory() as d:
        ulg, js, veh = f"{d}/fly.ulg", f"{d}/fly.json", f"{d}/vehicle.toml"
        # A vehicle of our own choosing (the OS4 made 0.7 kg): the log must carry the flight's.
        with open(veh, "w") as f:
            f.write("mass_kg = 0.7\n")
        subprocess.run([sil, "fly", "--controller", "lqr", "--scenario", "helix", "--duration", "20",
                        "--vehicle", veh, "--ulog", ulg, "--json", js], check=True, stdout=subprocess.DEVNULL)
        with open(js) as f:
            res = json.load(f)
        log = ULog(ulg)
    print(f"fly: {ulg}: {len(log.data_list)} topics, {sum(len(d.data['timestamp']) for d in log.data_list)} samples")
    gt = topic(log, "vehicle_local_position_groundtruth")
    sp = topic(log, "vehicle_local_position_setpoint")
    check(np.array_equal(gt["timestamp"], sp["timestamp"]), "truth and set-point share their 10 ms rows")
    rows = round(res["duration_s"] / 0.01) + 1
    check(len(gt["timestamp"]) == rows, f"{len(gt['timestamp'])} rows for {res['duration_s']} s (10 ms)")
    for ax in "xyz":
        rmse = math.sqrt(float(np.mean((gt[ax].astype(float) - sp[ax].astype(float)) ** 2)))
        want = res["axes"][ax]["rmse_m"]
        check(close(rmse, want), f"{ax} RMSE from the log {rmse:.6f} m = JSON {want:.6f} m")
    fe = math.sqrt(sum((float(gt[a][-1]) - float(sp[a][-1])) ** 2 for a in "xyz"))
    check(close(fe, res["final_error_m"], rel=1e-4), f"final error {fe:.6f} m = JSON {res['final_error_m']:.6f} m")
    p = log.initial_parameters
    n = table_length()
    check(len(p) == n, f"{len(p)} parameters (the table has {n})")
    check(close(p.get("VEH_MASS", 0), 0.7), f"VEH_MASS {p.get('VEH_MASS'):.4f} (the flight's vehicle file: 0.7)")
    check(p.get("CTL_ID") == 3.0, f"CTL_ID {p.get('CTL_ID')} (quaternion LQR)")
    est = topic(log, "vehicle_local_position")
    i = np.searchsorted(gt["timestamp"], est["timestamp"])
    ok = i < len(gt["timestamp"])
    err = np.sqrt(sum((est[a][ok] - gt[a][i[ok]]) ** 2 for a in "xyz"))
    rms = float(np.sqrt(np.mean(err ** 2)))
    want = res["estimator"]["rms_position_m"]
    check(len(est["timestamp"]) > 0.9 * rows and rms < 0.01,
          f"estimate logged ({len(est['timestamp'])} samples), RMS error {rms * 1e3:.2f} mm (JSON at 1 kHz: {want * 1e3:.2f} mm)")
    es = topic(log, "estimator_states")
    check(np.all(es["n_states"] == 16) and np.all(np.isfinite(es["covariances[0]"])), "estimator_states: 16 states, finite covariances")
    out = topic(log, "actuator_outputs")
    m = np.stack([out[f"output[{k}]"] for k in range(4)])
    check(np.all((m >= 0) & (m <= 1)) and np.all(out["noutputs"] == 4), "actuator_outputs: 4 motors within [0, 1]")


def check_hil(ulg, js):
    with open(js) as f:
        res = json.load(f)
    log = ULog(ulg)
    print(f"hil: {ulg}: {len(log.data_list)} topics, {sum(len(d.data['timestamp']) for d in log.data_list)} samples")
    gt = topic(log, "vehicle_local_position_groundtruth")
    last = [float(gt[a][-1]) for a in "xyz"]
    check(all(close(a, b, rel=1e-6, abs_=1e-5) for a, b in zip(last, res["final_pos_ned_m"])),
          f"last true position {np.round(last, 4)} = JSON final_pos_ned_m {np.round(res['final_pos_ned_m'], 4)}")
    check(abs(gt["timestamp"][-1] * 1e-6 - res["duration_s"]) < 0.01,
          f"log ends at {gt['timestamp'][-1] * 1e-6:.3f} s, the flight at {res['duration_s']:.3f} s")
    st = topic(log, "vehicle_status")
    armed = st["timestamp"][st["arming_state"] == 2]
    first = armed[0] * 1e-6 if len(armed) else None
    check(first is not None and res["armed_at_s"] is not None and abs(first - res["armed_at_s"]) < 1e-3,
          f"armed at {first} s in the log, {res['armed_at_s']} s in the JSON")
    texts = [m.message for m in log.logged_messages]
    check(texts == res["status_texts"], f"{len(texts)} logged messages = the JSON's STATUSTEXTs ({texts[:3]}…)")
    est = topic(log, "vehicle_local_position")
    # The truth in force at each estimate: the last true sample at or before it.
    i = np.searchsorted(gt["timestamp"], est["timestamp"], side="right") - 1
    ok = (i >= 0) & (est["timestamp"] >= armed[0]) if len(armed) else i >= 0
    err = np.sqrt(sum((est[a][ok].astype(float) - gt[a][i[ok]].astype(float)) ** 2 for a in "xyz"))
    mx = float(err.max()) if len(err) else float("nan")
    check(abs(mx - res["max_estimate_error_m"]) < 5e-3,
          f"largest armed estimate error {mx * 100:.2f} cm from the log, {res['max_estimate_error_m'] * 100:.2f} cm in the JSON (5 mm: one simulator step)")
    out = topic(log, "actuator_outputs")
    m = np.stack([out[f"output[{k}]"] for k in range(4)])
    check(len(out["timestamp"]) >= 0.9 * res["steps"] and np.all((m >= 0) & (m <= 1)),
          f"{len(out['timestamp'])} motor commands for {res['steps']} steps, all within [0, 1]")
    p = log.initial_parameters
    n = table_length()
    check(len(p) == n and "MOT_FRAME" in p, f"{len(p)} parameters of {n}, MOT_FRAME = {p.get('MOT_FRAME')}")
    sp = topic(log, "vehicle_local_position_setpoint")
    check(len(sp["timestamp"]) > 0, f"{len(sp['timestamp'])} set-points; the last ({sp['x'][-1]:.2f}, {sp['y'][-1]:.2f}, {sp['z'][-1]:.2f}) m")


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "fly":
        check_fly(sys.argv[2])
    elif len(sys.argv) == 4 and sys.argv[1] == "hil":
        check_hil(sys.argv[2], sys.argv[3])
    else:
        raise SystemExit(__doc__)
    print(check.summary())
    sys.exit(check.exit_code())


if __name__ == "__main__":
    main()
