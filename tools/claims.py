#!/usr/bin/env python3
"""Holds the figures the README and the book state to the measurements the
checks wrote (`./test.sh` gathers them into target/measurements.json).

A stated figure is marked where it stands, invisible in the rendered page:

    at most <!--m:image_step_instructions_quaternion-->68 232<!--/m--> instructions

    claims.py check target/measurements.json   # every marked figure within its key's tolerance
    claims.py write target/measurements.json   # rewrite every marked figure from the measurements
    claims.py selftest target/measurements.json  # a planted drift must fail the check

`check` fails on a marked figure whose key no check measured, and on one
that drifted beyond the tolerance TOLERANCES gives for its key (each with
its reason); `write` keeps each figure's style (decimals, grouping, a
trailing ×). Files: README.md and every page under docs/book/src (the
generated study report apart). `check` also holds the introduction's copy
of the study's headline table to the committed report (docs/study) and that
report's set-point columns to the quick report ./test.sh makes. Ends with
`claims check: N passed, N failed`.
"""
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

from measure import budgets

ROOT = Path(__file__).resolve().parent.parent
MARK = re.compile(r"<!--m:([a-z0-9_]+)-->(.*?)<!--/m-->", re.DOTALL)
NUMBER = re.compile(r"-?[0-9][0-9  ,]*(?:\.[0-9]+)?(?:[eE]-?[0-9]+)?")

# (pattern on the key, relative tolerance, absolute tolerance, why).
TOLERANCES = [
    (r"^budget_", 0.0, 0.0, "a budget (firmware/stm32f405/src/budgets.rs) is stated exactly"),
    (r"^fault_.*_s$", 0.10, 0.5,
     "MAVSDK injects a fault on the wall clock: where in the simulated flight it lands moves by tenths of a second"),
    (r"^fault_", 0.0, 0.15,
     ("MAVSDK injects a fault on the wall clock: where in the flight (and its noise) it lands moves the "
      "distance from run to run (the same landing 0.6, 5.7, 9.7 and 12.4 cm from the hold in four runs; "
      "the check's own bound is 50 cm)")),
    (r"_mean_icount$", 0.01, 0.0,
     "a lockstep QEMU flight's mean step: the host's timing moves where its samples pre-empt a step"),
    (r"_link_hold_worst_icount$", 0.50, 0.0,
     ("the longest of a flood's link holds in QEMU: which hold the host's frames pre-empt moves it "
      "(3 166 to 3 273 in most runs, 4 666 in two of the Crazyflie's); the check holds it to the "
      "budget of 6 000")),
    (r"_worst_icount$", 0.10, 0.0,
     "a lockstep QEMU flight's worst step: one host-timed pre-emption moves it by up to ~5 %"),
    (r"instructions", 0.005, 0.0,
     "QEMU counts instructions deterministically; 0.5 % is the drift a compiler release brings"),
    (r"load_pct", 0.0, 0.6, "derived from an instruction count, shown to whole percent"),
    (r"_qemu_stack_tasks_bytes$", 0.10, 0.0,
     ("an image's stack in its tasks: how deep they nest depends on where the host's frames pre-empt them "
      "(firmware-crtp: 35 544 and 34 996 B in two runs)")),
    (r"_bytes$", 0.005, 0.0, "sizes from `size -A`; 0.5 % is the drift a compiler release brings"),
    (r"_closed_loop_cost$", 0.005, 0.0, "a deterministic QEMU flight's cost; 0.5 % for a compiler release"),
    (r"^peer_.*_pct$", 0.0, 0.2, "a ratio of two deterministic costs, shown to a tenth"),
    (r"^peer_", 0.05, 0.0, "a ratio of two instruction counts, shown to whole units"),
    (r"_radio_\d+_(lost|duplicates_dropped)_pct$", 0.2, 1.0,
     ("the modelled radio sends on the wall clock (its polls, the image's pace in QEMU, where the shadows "
      "fall): which of its packets a shadow takes, and so what share it loses and doubles, moves from run "
      "to run")),
    (r"^crtp_sil_fix_faults_", 0.0, 0.01,
     ("cflib's live hover, in real time: where its commands and the faults land in the plant's time moves "
      "the hover's worst distance by millimetres from run to run")),
    (r"_pct", 0.0, 0.5, "a share of flights, shown to a tenth"),
    (r"_s$", 0.05, 0.01, "a flight's settling time; the last bit of the platform's libm moves it"),
    (r"_effort$", 0.10, 0.0005, "a flight's motor effort; the last bit of the platform's libm moves it"),
    (r"_(peak|hover)_rotor$", 0.05, 0.005, "a flight's fastest rotor, or hover's speed; the last bit of the platform's libm moves it"),
    (r"_ratio$", 0.02, 0.0, "a ratio of two flights' errors, shown to a hundredth"),
    (r"_(deg|mps)$", 0.10, 0.005, "an estimator's RMS error; the last bit of the platform's libm moves it"),
    (r"^nees_mean$", 0.02, 0.0, "a mean over 50 seeded flights, shown to a tenth"),
    (r"_m$", 0.10, 0.0005, "a flight's error; the last bit of the platform's libm moves it"),
    (r"_figure8_(worst|rms)_cm$", 0.25, 0.5,
     ("cflib's live flight of an uploaded trajectory: where its commands land in the plant's time moves by "
      "a step or more from run to run")),
    (r"_motion_overshoot_cm$", 0.25, 1.0,
     ("cflib's live velocity set-points: where a stop lands in the plant's time moves by a step or more "
      "from run to run")),
    (r"diff", 0.0, 1e-9, "an upper bound the page states; the measurement must not exceed it"),
    (r".", 0.0, 0.0, "anything else is stated exactly"),
]


def tolerance(key):
    for pat, rel, abs_, why in TOLERANCES:
        if re.search(pat, key):
            return rel, abs_, why
    raise AssertionError("the last pattern matches every key")


def pages():
    book = ROOT / "docs" / "book" / "src"
    return [ROOT / "README.md"] + sorted(p for p in book.rglob("*.md") if "study" not in p.relative_to(book).parts)


def parse(text):
    m = NUMBER.search(text)
    if not m:
        return None
    return float(m.group(0).replace(" ", "").replace("\u2009", "").replace(",", ""))


def fmt(value, like):
    """`value` written as the figure `like` is (decimals, thousands grouping)."""
    m = NUMBER.search(like)
    shown = m.group(0)
    decimals = len(shown.split(".")[1]) if "." in shown else 0
    out = f"{value:,.{decimals}f}"
    sep = " " if " " in shown else "\u2009" if "\u2009" in shown else "," if "," in shown else ""
    out = out.replace(",", sep)
    return like[: m.start()] + out + like[m.end():]


def load(path):
    """The measurements at `path`, with the budgets they are held to."""
    with open(path) as f:
        d = json.load(f)
    out = {k: v["value"] for k, v in d["measurements"].items()}
    out.update(budgets())
    return out


def within(key, stated, measured):
    rel, abs_, _ = tolerance(key)
    if "diff" in key:
        # A stated bound: the measurement must be at or under it.
        return measured <= stated + abs_
    return abs(stated - measured) <= max(rel * abs(measured), abs_)


def check(measured, files, root=ROOT):
    passed = failed = 0
    for f in files:
        text = f.read_text()
        for m in MARK.finditer(text):
            key, shown = m.group(1), m.group(2)
            stated = parse(shown)
            line = text.count("\n", 0, m.start()) + 1
            where = f"{f.relative_to(root)}:{line}"
            if key not in measured:
                failed += 1
                print(f"FAIL {where}: {key} = {shown!r}, which no check measured")
            elif stated is None or not within(key, stated, measured[key]):
                failed += 1
                print(f"FAIL {where}: {key} states {shown!r}, measured {measured[key]:g} "
                      f"(tolerance: {tolerance(key)[2]})")
            else:
                passed += 1
    return passed, failed


def headline_rows(path):
    """The study's headline table in `path` (a page or a report's index.md):
    {controller: [cells]}, the table whose header starts `| controller`
    and names the set-point settling."""
    rows, inside = {}, False
    for line in path.read_text().splitlines():
        if line.startswith("| controller") and "set-point settling" in line:
            inside = True
            continue
        if inside:
            if not line.startswith("|"):
                break
            cells = [c.strip() for c in line.strip("|").split("|")]
            if not set(cells[0]) <= set("-"):
                rows[cells[0]] = cells[1:]
    return rows


def study_tables(root=ROOT):
    """The introduction's copy of the study's headline table against the
    report it is copied from (docs/study, `sil-host report`'s output), and
    that report's set-point columns (settling, overshoot: the quick report
    flies the same set-point) against the report ./test.sh just made
    (target/report-quick). Returns (passed, failed)."""
    passed = failed = 0
    intro = headline_rows(root / "docs" / "book" / "src" / "introduction.md")
    study = headline_rows(root / "docs" / "study" / "index.md")
    quick_md = root / "target" / "report-quick" / "index.md"
    quick = headline_rows(quick_md) if quick_md.is_file() else None
    if not intro or not study:
        print("FAIL study table: no headline table in the introduction or docs/study/index.md")
        return 0, 1
    for name, cells in intro.items():
        theirs = study.get(name)
        if theirs is None or theirs[: len(cells)] != cells:
            failed += 1
            print(f"FAIL introduction.md's study table, {name}: {cells} but docs/study has {theirs}")
        else:
            passed += 1
        if quick is not None:
            q = quick.get(name)
            if q is None or q[:2] != cells[:2]:
                failed += 1
                print(f"FAIL the study's set-point figures, {name}: {cells[:2]} but a fresh report has {q and q[:2]}")
            else:
                passed += 1
    return passed, failed


def write(measured, files):
    for f in files:
        text = f.read_text()

        def repl(m):
            key, shown = m.group(1), m.group(2)
            if key not in measured:
                return m.group(0)
            value = measured[key]
            if "diff" in key:
                return m.group(0)  # a stated bound is the author's, not a measurement
            return f"<!--m:{key}-->{fmt(value, shown)}<!--/m-->"

        new = MARK.sub(repl, text)
        if new != text:
            f.write_text(new)
            print(f"wrote {f.relative_to(ROOT)}")


def main():
    if len(sys.argv) != 3 or sys.argv[1] not in ("check", "write", "selftest"):
        raise SystemExit(__doc__)
    measured = load(sys.argv[2])
    if sys.argv[1] == "write":
        write(measured, pages())
        return
    if sys.argv[1] == "selftest":
        # A planted drift: the README's first marked measurement moved by 10 %.
        with tempfile.TemporaryDirectory() as d:
            copy = Path(d) / "README.md"
            shutil.copy(ROOT / "README.md", copy)
            text = copy.read_text()
            # The first marked figure that is a measurement (a stated bound
            # may be raised without being wrong).
            m = next(m for m in MARK.finditer(text) if "diff" not in m.group(1))
            key, shown = m.group(1), m.group(2)
            drifted = fmt(parse(shown) * 1.1 + 1, shown)
            copy.write_text(text[: m.start(2)] + drifted + text[m.end(2):])
            _, failed = check(measured, [copy], root=Path(d))
        ok = failed == 1
        print(f"claims selftest: a planted drift of {key} ({shown!r} -> {drifted!r}) "
              f"{'fails the check' if ok else 'was NOT caught'}")
        print(f"claims check: {int(ok)} passed, {int(not ok)} failed")
        sys.exit(0 if ok else 1)
    passed, failed = check(measured, pages())
    p, f = study_tables()
    passed, failed = passed + p, failed + f
    print(f"claims check: {passed} passed, {failed} failed")
    sys.exit(1 if failed or not passed else 0)


if __name__ == "__main__":
    main()
