"""One rotorpy flight held to another's figures (the peer table's windows,
rotorpy's truth): `tools/rotorpy_hil.py --beat` and, for flights flown
apart, `./test.sh` call it.

    python3 tools/beat.py MINE.json THEIRS.json [--windows whole,steady]

MINE and THEIRS are two flights' summaries (`rotorpy_hil.py --json`) on the
same vehicle and reference. MINE's RMSE over each window both have (a
scenario's whole span and its steady laps; a trajectory's whole, which is
the trajectory) must not exceed THEIRS', and where both flew a step its
settling time into 2 cm must not be later. `--windows` names the windows
held (a step's steady hold on the true state is SE3's 0 m, which no
flight through an estimator meets: `./test.sh` holds a step's whole window
and settling). Prints one `rotorpy check:` line per figure and exits
non-zero when one fails.
"""

import json
import sys


def beat(mine, theirs, who="this flight", whom="the other", windows=("whole", "steady")):
    """[(passed, line)] for each figure of `mine` held to `theirs` (the
    summaries' `rotorpy` parts) over `windows`."""
    out = []
    for window in windows:
        a = mine["windows"].get(window)
        b = theirs["windows"].get(window)
        if not isinstance(a, dict) or not isinstance(b, dict):
            continue
        ok = a["rmse_m"] <= b["rmse_m"]
        w = a["window_s"]
        line = (f"rotorpy check: {int(ok)} passed, {int(not ok)} failed ({who} {100 * a['rmse_m']:.2f} cm "
                f"RMSE over {w[0]:g}-{w[1]:.0f} s against {whom}'s {100 * b['rmse_m']:.2f} cm on the "
                "same vehicle and reference, rotorpy's truth)")
        out.append((ok, line))
    a = mine["windows"].get("settling_s")
    b = theirs["windows"].get("settling_s")
    if "settling_s" in theirs["windows"]:
        # A step: settled into 2 cm no later (never settling loses).
        ok = a is not None and (b is None or a <= b)
        def when(t):
            return "never" if t is None else f"{t:.2f} s"
        line = (f"rotorpy check: {int(ok)} passed, {int(not ok)} failed ({who} settles into 2 cm at "
                f"{when(a)} against {whom}'s {when(b)} on the same vehicle and step, rotorpy's truth)")
        out.append((ok, line))
    return out


def main():
    args = sys.argv[1:]
    windows = ("whole", "steady")
    if len(args) == 4 and args[2] == "--windows":
        windows = tuple(args[3].split(","))
        args = args[:2]
    if len(args) != 2:
        sys.exit(__doc__)
    flights = []
    for path in args:
        with open(path) as f:
            flights.append(json.load(f))
    mine, theirs = flights
    checks = beat(mine["rotorpy"], theirs["rotorpy"], mine.get("controller", args[0]),
                  theirs.get("controller", args[1]), windows)
    for _, line in checks:
        print(line)
    sys.exit(0 if checks and all(ok for ok, _ in checks) else 1)


if __name__ == "__main__":
    main()
