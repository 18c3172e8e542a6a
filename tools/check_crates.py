#!/usr/bin/env python3
"""The book's crate graph against what cargo has: the table in
docs/book/src/architecture.md between its `crates:` markers lists, for each
of the workspace's crates, the workspace crates it depends on (normal
dependencies; dev-dependencies apart, in their own column), and this
check fails when it differs from `cargo metadata` (a dependency added or
dropped without the page saying so).

    python3 tools/check_crates.py docs/book/src/architecture.md
    python3 tools/check_crates.py --table     # the table as cargo has it
"""
import argparse
import json
import re
import subprocess
import sys

from fctools.checks import Checks

BEGIN = "<!-- crates: begin (tools/check_crates.py) -->"
END = "<!-- crates: end -->"


def graph():
    """{crate: (normal deps, dev deps)}, workspace crates only, features apart."""
    out = subprocess.run(["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
                         check=True, capture_output=True, text=True).stdout
    packages = json.loads(out)["packages"]
    names = {p["name"] for p in packages}
    g = {}
    for p in packages:
        normal, dev = set(), set()
        for d in p["dependencies"]:
            if d["name"] in names:
                (dev if d["kind"] == "dev" else normal).add(d["name"])
        g[p["name"]] = (normal, dev - normal)
    return g


def cell(names):
    return ", ".join(f"`{n}`" for n in sorted(names)) or "none"


def table(g):
    rows = ["| crate | depends on | and in its tests |", "|---|---|---|"]
    rows += [f"| `{c}` | {cell(n)} | {cell(d)} |" for c, (n, d) in sorted(g.items())]
    return "\n".join(rows)


def parse(text):
    """The page's table: {crate: (normal, dev)}."""
    m = re.search(re.escape(BEGIN) + r"(.*?)" + re.escape(END), text, re.DOTALL)
    if not m:
        return None
    g = {}
    for line in m.group(1).splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not cells[0].startswith("`"):
            continue
        names = [set(re.findall(r"`([^`]+)`", c)) for c in cells]
        g[next(iter(names[0]))] = (names[1], names[2])
    return g


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("page", nargs="?")
    ap.add_argument("--table", action="store_true", help="print the table as cargo has it")
    a = ap.parse_args()
    g = graph()
    if a.table or not a.page:
        print(table(g))
        return 0
    check = Checks("crates")
    with open(a.page) as f:
        page = parse(f.read())
    check(page is not None, f"{a.page} holds the crate table between {BEGIN!r} and {END!r}")
    if page is not None:
        for c in sorted(set(g) | set(page)):
            have, said = g.get(c), page.get(c)
            check(have == said, f"{c}: cargo has {have and tuple(map(sorted, have))}, the page says "
                                f"{said and tuple(map(sorted, said))}")
    print(check.summary())
    return check.exit_code()


if __name__ == "__main__":
    sys.exit(main())
