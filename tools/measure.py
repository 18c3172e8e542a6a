"""Measurements a check writes for `./test.sh` to gather into
`target/measurements.json` (tools/claims.py holds the README and the book
to them): one JSON line each, appended to the file `$FC_MEASUREMENTS` names;
nothing when it is unset (a tool run by hand). The Rust twin is
`e2e_tests::measure` (tests/lib.rs)."""
import json
import math
import os
import re

BUDGETS_RS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "firmware", "stm32f405", "src", "budgets.rs")


def budgets():
    """The budgets of firmware/stm32f405/src/budgets.rs, the one place they
    are set: {"budget_<name in lower case>": value}."""
    out = {}
    with open(BUDGETS_RS) as f:
        for m in re.finditer(r"pub const ([A-Z0-9_]+): u32 = ([0-9_]+)(?: \* ([0-9_]+))?;", f.read()):
            v = int(m.group(2).replace("_", "")) * int((m.group(3) or "1").replace("_", ""))
            out["budget_" + m.group(1).lower()] = v
    if len(out) < 10:
        raise SystemExit(f"{BUDGETS_RS}: only {len(out)} budgets read")
    return out


def record(key, value, unit, source):
    """Appends `key` = `value` [`unit`], measured by the check `source`."""
    path = os.environ.get("FC_MEASUREMENTS")
    if not path:
        return
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"measurement {key} is {value}")
    line = json.dumps({"key": key, "value": value, "unit": unit, "source": source}) + "\n"
    with open(path, "a") as f:
        f.write(line)


def gather(lines_path, out_path, extra=()):
    """The JSON lines at `lines_path` as one file at `out_path`:
    `{"measurements": {key: {"value", "unit", "source", "values"}}}`, the
    last value written for a key standing for it, every value kept."""
    out = {}
    with open(lines_path) as f:
        for line in f:
            m = json.loads(line)
            e = out.setdefault(m["key"], {"values": []})
            e.update(value=m["value"], unit=m["unit"], source=m["source"])
            e["values"].append(m["value"])
    for key, value, unit, source in extra:
        out[key] = {"value": value, "unit": unit, "source": source, "values": [value]}
    with open(out_path, "w") as f:
        json.dump({"measurements": dict(sorted(out.items()))}, f, indent=2)
        f.write("\n")
    return out


if __name__ == "__main__":
    # measure.py LINES OUT [KEY=VALUE:UNIT:SOURCE ...]: gathers the lines, with extra figures.
    import sys

    extra = []
    for arg in sys.argv[3:]:
        kv, unit, source = arg.split(":", 2)
        k, v = kv.split("=")
        extra.append((k, float(v), unit, source))
    n = gather(sys.argv[1], sys.argv[2], extra)
    print(f"{len(n)} measurements in {sys.argv[2]}")
