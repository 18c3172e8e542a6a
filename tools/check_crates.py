#!/usr/bin/env python3
"""The book's crate graph against what cargo has: the table in
docs/book/src/architecture.md between its `crates:` markers lists, for each
of the workspace's crates, the workspace crates it depends on (normal
dependencies; dev-dependencies apart, in their own column), and this
check fails when it differs from `cargo metadata` (a dependency added or
dropped without the page saying so). It also fails when two of a crate's
top-level modules depend on each other, directly or round a circle
(`tools/fctools/modules.py`: `crate::x…` in code; the crate root and test
code apart), and `--selftest` shows that check failing on a planted circle.

    python3 tools/check_crates.py docs/book/src/architecture.md
    python3 tools/check_crates.py --table     # the table as cargo has it
    python3 tools/check_crates.py --selftest  # a planted circle is found
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

from fctools.checks import Checks
from fctools.modules import circles, edges

BEGIN = "<!-- crates: begin (tools/check_crates.py) -->"
END = "<!-- crates: end -->"


def packages():
    """The workspace's packages, as `cargo metadata` has them."""
    out = subprocess.run(["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
                         check=True, capture_output=True, text=True).stdout
    return json.loads(out)["packages"]


def libraries(packages_):
    """{crate: its library's source folder}, for the crates with a `lib.rs`."""
    out = {}
    for p in packages_:
        for t in p["targets"]:
            if "lib" in t["kind"] and os.path.basename(t["src_path"]) == "lib.rs":
                out[p["name"]] = os.path.dirname(t["src_path"])
    return out


def selftest():
    """A crate of two modules naming each other is a circle; one naming the
    other only in a comment, a string or its tests is not."""
    check = Checks("crates-selftest")
    with tempfile.TemporaryDirectory() as d:
        def crate(a, b):
            with open(os.path.join(d, "lib.rs"), "w") as f:
                f.write("pub mod a;\npub mod b;\n")
            for name, text in (("a.rs", a), ("b.rs", b)):
                with open(os.path.join(d, name), "w") as f:
                    f.write(text)
            return circles(edges(d))
        found = crate("use crate::b::B;\npub struct A;\n", "pub struct B(pub crate::a::A);\n")
        check(found == [["a", "b"]], f"a planted circle a <-> b is found: {found}")
        found = crate("use crate::{x, b::B};\n", "use crate::{a::{self, A}};\n")
        check(found == [["a", "b"]], f"and inside `use crate::{{…}}` groups: {found}")
        found = crate("use crate::b::B;\n",
                      '//! [`A`](crate::a::A)\nconst S: &str = "crate::a";\n'
                      "#[cfg(test)]\nmod tests {\n    use crate::a::A;\n}\n")
        check(found == [], f"a comment, a string and a test module are no edge: {found}")
    print(check.summary())
    return check.exit_code()


def graph(packages_):
    """{crate: (normal deps, dev deps)}, workspace crates only, features apart."""
    names = {p["name"] for p in packages_}
    g = {}
    for p in packages_:
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
    ap.add_argument("--selftest", action="store_true", help="the circle check against planted crates")
    a = ap.parse_args()
    if a.selftest:
        return selftest()
    packages_ = packages()
    g = graph(packages_)
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
    for c, src in sorted(libraries(packages_).items()):
        found = circles(edges(src))
        check(not found, f"{c}: no two top-level modules depend on each other"
                         + (f" (circles: {'; '.join(' <-> '.join(x) for x in found)})" if found else ""))
    print(check.summary())
    return check.exit_code()


if __name__ == "__main__":
    sys.exit(main())
