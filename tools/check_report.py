#!/usr/bin/env python3
"""Checks a `sil-host report` directory as a reader would meet it: index.md
and index.html exist, every relative link in index.md (figures, PNG/SVG,
sweep pages) resolves to a non-empty file, PNGs are PNGs and SVGs are SVG,
the HTML carries its figures inline, and the report links into the book. Prints `report check: N passed, M
failed` (the whole is one check: 1 passed or 1 failed, each part
on a line of its own) and exits non-zero on any failure."""
import re
import sys
from pathlib import Path

from fctools.checks import Checks

d = Path(sys.argv[1])
check = Checks("report", quiet=True)


md_path, html_path = d / "index.md", d / "index.html"
check(md_path.is_file(), "index.md exists")
check(html_path.is_file(), "index.html exists")
md = md_path.read_text() if md_path.is_file() else ""
html = html_path.read_text() if html_path.is_file() else ""
links = sorted(set(re.findall(r"\]\(([^)#][^)]*)\)", md)))
links = [l for l in links if "://" not in l]
check(len(links) >= 28, f"index.md links at least 28 files (found {len(links)})")
for link in links:
    f = d / link
    ok = f.is_file() and f.stat().st_size > 0
    check(ok, f"linked file {link} exists")
    if ok and f.suffix == ".png":
        check(f.read_bytes()[1:4] == b"PNG", f"{link} is a PNG")
    if ok and f.suffix == ".svg":
        check("<svg" in f.read_text(errors="replace"), f"{link} is an SVG")
for section in ["## Headline", "## Figures", "Table 4.", "## Prediction horizon", "## Robustness", "## Instructions per step"]:
    check(section in md, f"index.md has {section!r}")
book = [l for l in links if "docs/book/src/" in l and l.endswith(".md")]
check(len(book) >= 5 and "## Read on" in md, f"index.md links into the book's chapters (found {len(book)})")
check(html.count("<svg") >= 14 and "<img" not in html, "index.html inlines its figures")
print(f"{check.passed} of {len(check.results)} parts of the report hold")
print(f"report check: {int(not check.failed)} passed, {int(bool(check.failed))} failed")
sys.exit(check.exit_code())
