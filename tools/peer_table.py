#!/usr/bin/env python3
"""The peer table: our controllers (PD, LQR, the fast MPC) and rotorpy's SE3
on rotorpy's vehicles and references, every figure from rotorpy's true
state (`tools/rotorpy_hil.py`'s windows: RMSE, worst and final distance,
settling, motor effort, peak rotor speed, over the whole span and its
steady part).

Ours fly twice: through their own sensors and estimator (the whole flight
controller, `--state estimate`) and on rotorpy's true state (the controller
alone, `--state truth`), as SE3 flies.

    python3 tools/peer_table.py args circle
        a reference's flight as tools/rotorpy_hil.py's arguments (./test.sh
        flies its references with them)
    python3 tools/peer_table.py book > /tmp/table.md
        the book's tables (docs/book/src/peers.md): the Crazyflie flights
        `./test.sh` flies, figures as claim marks (`claims.py write` fills
        them from a run's measurements)
    python3 tools/peer_table.py fly docs/peers [--sil-host target/release/sil-host] [--only REF]
        flies the whole table (every controller x state x vehicle x
        reference, two flights at a time, about 20 minutes; --only: that
        reference's rows, the others kept as flown) and writes
        docs/peers/peers.json (each flight's figures and the package
        versions it flew with) and docs/peers/index.md (the tables);
        `sil-host report` copies them into the report
"""
import argparse
import datetime
import json
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

HERE = os.path.dirname(os.path.abspath(__file__))

# (controller, state, row title); SE3 flies rotorpy's true state only.
# A state "…-nopreview" flies ours with the preview off (rotorpy_hil.py
# --no-preview): the MPC extrapolates each step's set-point.
ROWS = [("pd", "estimate", "PD (ours, own estimator)"), ("lqr", "estimate", "LQR (ours, own estimator)"),
        ("mpc", "estimate", "MPC fast (ours, own estimator)"), ("pd", "truth", "PD (ours, true state)"),
        ("lqr", "truth", "LQR (ours, true state)"), ("mpc", "truth", "MPC fast (ours, true state)"),
        ("se3", "truth", "SE3 (rotorpy, true state)")]
# The uploaded trajectory's rows add the MPC with its preview off.
NO_PREVIEW = [("mpc", "estimate-nopreview", "MPC fast, preview off (ours, own estimator)"),
              ("mpc", "truth-nopreview", "MPC fast, preview off (ours, true state)")]


def rows(ref):
    """The rows of reference `ref`'s table."""
    return ROWS + (NO_PREVIEW if ref == "traj8" else [])
# The rows ./test.sh flies (the book's tables) on the Crazyflie: the step's
# holds (ours) and SE3; the LQR's circle (the MPC's bound); the MPC through
# its estimator and on the true state, and SE3, on the circle and the
# figure-8 (the goal it is held to).
BOOK = {"step": [("pd", "estimate"), ("lqr", "estimate"), ("mpc", "estimate"), ("se3", "truth")],
        "circle": [("lqr", "estimate"), ("mpc", "estimate"), ("mpc", "truth"), ("se3", "truth")],
        "eight": [("mpc", "estimate"), ("mpc", "truth"), ("se3", "truth")],
        "traj8": [("pd", "estimate"), ("mpc", "estimate"), ("mpc", "estimate-nopreview"), ("se3", "truth")]}


def book_rows(ref):
    return [r for r in rows(ref) if (r[0], r[1]) in BOOK[ref]]


VEHICLES = [("crazyflie", "Crazyflie"), ("hummingbird", "Hummingbird")]
REFERENCES = [("step", "step to (1, 0, −1) m at 5 s; whole 5–30 s, steady 10–30 s"),
              ("circle", "circle, R 2 m, 20 s lap, from 3 s; whole 3–25 s, steady 8–25 s"),
              ("eight", "figure-8, A 1 m, 6 s lap, from 3 s; whole 3–23 s, steady 9–23 s"),
              ("traj8", ("cflib's figure-8 (`autonomous_sequence_high_level.py`: 10 pieces, 7.28 s), uploaded, "
                         "from a hover 1 m up at 5 s; whole: the trajectory 5–12.28 s, steady: the hold at its "
                         "end 12.28–14.5 s"))]
# The flight of each reference (tools/rotorpy_hil.py's arguments).
# ./test.sh reads them (`peer_table.py args REF`), so its flights are these;
# the bounds it holds them to are its own.
FLIGHTS = {"step": ["--waypoint", "0,0,0,-1", "--waypoint", "5,1,0,-1", "--duration", "30", "--hold-from", "10"],
           "circle": ["--scenario", "circle", "--duration", "25"],
           "eight": ["--scenario", "eight", "--duration", "23"],
           "traj8": ["--trajectory", "cflib:figure8", "--duration", "14.5"]}
# The table's own bound on the step's hold: loose, so that every row is
# flown and stated (./test.sh holds its rows to 2 cm).
TABLE_STEP_BOUND = ["--max-hold-error", "0.05"]
FIGURES = [("whole", "rmse_m"), ("steady", "rmse_m"), ("whole", "worst_m"), ("steady", "worst_m"),
           ("whole", "final_m")]
HEADER = ["RMSE whole", "RMSE steady", "worst whole", "worst steady", "final"]


def measure_name(controller, state, vehicle, ref):
    """The flight's name in the measurements: rotorpy_NAME_* (rotorpy_hil.py --measure)."""
    off = "_nopreview" if state.endswith("-nopreview") else ""
    truth = "_truth" if state.startswith("truth") and controller != "se3" else ""
    return f"{controller}{off}{truth}_{vehicle}_{ref}"


def header(ref):
    cols = HEADER + (["settling s"] if ref == "step" else []) + ["effort", "peak rotor"]
    return ["| controller | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]


def cells(ref, get):
    """A row's cells; `get(window, figure)` gives each as text."""
    out = [get(w, f) for w, f in FIGURES]
    if ref == "step":
        out.append(get(None, "settling_s"))
    out.append(get("whole", "effort"))
    out.append(get("whole", "peak_rotor"))
    return out


def book():
    for v, vt in VEHICLES[:1]:
        for r, rt in REFERENCES:
            print(f"**{vt}, {rt}** (m)\n")
            print("\n".join(header(r)))
            for c, state, title in book_rows(r):
                k = "rotorpy_" + measure_name(c, state, v, r)

                def mark(w, f, k=k):
                    key = f"{k}_settling_s" if w is None else f"{k}_{w}_{f}"
                    return f"<!--m:{key}-->{'0.00' if w is None else '0.0000'}<!--/m-->"
                print(f"| {title} | " + " | ".join(cells(r, mark)) + " |")
            print()


def fly_one(job):
    sil_host, out_dir, n, (c, state, v, r) = job
    name = measure_name(c, state, v, r)
    path = os.path.join(out_dir, "flights", f"{name}.json")
    cmd = [sys.executable, os.path.join(HERE, "rotorpy_hil.py"), "--sil-host", sil_host, "--controller", c,
           "--vehicle", v, "--port", str(4800 + n), "--gcs-port", str(14800 + n), "--truth-port", str(15800 + n),
           "--json", path] + FLIGHTS[r] + (TABLE_STEP_BOUND if r == "step" else [])
    if c != "se3":
        cmd += ["--state", state.split("-")[0]] + (["--no-preview"] if state.endswith("-nopreview") else [])
    p = subprocess.run(cmd, check=False, capture_output=True, text=True)
    check = [ln for ln in p.stdout.splitlines() if ln.startswith("rotorpy check:")]
    print(f"{name}: {check[-1] if check else 'no check line'}", file=sys.stderr)
    if p.returncode != 0 or not os.path.exists(path):
        sys.stderr.write(p.stderr[-2000:])
        raise SystemExit(f"the flight {name} failed")
    with open(path) as f:
        return name, json.load(f)


def fmt(x, unit_s=False):
    return "—" if x is None else (f"{x:.2f}" if unit_s else f"{x:.4f}")


def tables(flights):
    lines = []
    for v, vt in VEHICLES:
        for r, rt in REFERENCES:
            lines += [f"**{vt}, {rt}** (m)", ""] + header(r)
            for c, state, title in rows(r):
                w = flights[measure_name(c, state, v, r)]["rotorpy"]["windows"]

                def get(win, fig, w=w):
                    return fmt(w.get("settling_s"), True) if win is None else fmt(w[win][fig])
                lines.append(f"| {title} | " + " | ".join(cells(r, get)) + " |")
            lines.append("")
    return lines


def fly(a):
    os.makedirs(os.path.join(a.out, "flights"), exist_ok=True)
    refs = a.only or [r for r, _ in REFERENCES]
    combos = [(c, state, v, r) for v, _ in VEHICLES for r, _ in REFERENCES if r in refs for c, state, _ in rows(r)]
    jobs = [(a.sil_host, a.out, n, combo) for n, combo in enumerate(combos)]
    with ThreadPoolExecutor(max_workers=a.jobs) as pool:
        flights = dict(pool.map(fly_one, jobs))
    if a.only:
        # The other references' flights as they were flown (their summaries).
        for name in os.listdir(os.path.join(a.out, "flights")):
            if name.endswith(".json") and name[:-5] not in flights:
                with open(os.path.join(a.out, "flights", name)) as f:
                    flights[name[:-5]] = json.load(f)
    versions = next(iter(flights.values()))["versions"]
    flown = datetime.date.today().isoformat()
    if a.only:
        with open(os.path.join(a.out, "peers.json")) as f:
            before = json.load(f)["flown"]
        flown = f"{before.split(' (')[0]} ({', '.join(refs)}: {flown})"
    with open(os.path.join(a.out, "peers.json"), "w") as f:
        json.dump({"flown": flown, "versions": versions,
                   "flights": {k: {"controller": d["controller"], "state": d.get("state", "truth"),
                                   "rotorpy": d["rotorpy"]["windows"], "versions": d["versions"]}
                               for k, d in sorted(flights.items())}}, f, indent=1)
        f.write("\n")
    pinned = ", ".join(f"{k} {v}" for k, v in versions.items() if v)
    text = ["# Against the controllers users fly: the whole table", "",
            "Written by `python3 tools/peer_table.py fly docs/peers` (every flight's figures in",
            ("[`peers.json`](peers.json), their summaries under `flights/`), flown on "
            f"{flown} with {pinned}."),
            "Every figure is rotorpy's true state against the reference; how the flights",
            "compare and what the figures mean: the book's \"Against the controllers users",
            "fly\". `./test.sh` flies the Crazyflie's rows the book states and holds them.", ""]
    text += tables(flights)
    with open(os.path.join(a.out, "index.md"), "w") as f:
        f.write("\n".join(text).rstrip() + "\n")
    # The flights' own summaries are bulky traces of numbers: keep the figures only.
    for name, d in flights.items():
        with open(os.path.join(a.out, "flights", f"{name}.json"), "w") as f:
            json.dump({"controller": d["controller"], "state": d.get("state", "truth"), "versions": d["versions"],
                       "rotorpy": d["rotorpy"]}, f, indent=1)
            f.write("\n")
    print(f"wrote {a.out}/index.md and {a.out}/peers.json ({len(flights)} flights)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="what", required=True)
    sub.add_parser("book", help="the book's tables, figures as claim marks")
    g = sub.add_parser("args", help="a reference's flight, as rotorpy_hil.py's arguments (./test.sh reads them)")
    g.add_argument("ref", choices=sorted(FLIGHTS))
    f = sub.add_parser("fly", help="fly the whole table and write it to OUT")
    f.add_argument("out")
    f.add_argument("--sil-host", default="target/release/sil-host")
    f.add_argument("--jobs", type=int, default=2, help="flights at a time (each about one core)")
    f.add_argument("--only", action="append", choices=sorted(FLIGHTS),
                   help="fly only this reference's rows (repeatable); the others are kept as flown")
    a = ap.parse_args()
    if a.what == "book":
        book()
    elif a.what == "args":
        print(" ".join(FLIGHTS[a.ref]))
    else:
        fly(a)


if __name__ == "__main__":
    main()
