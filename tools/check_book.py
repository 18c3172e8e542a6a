#!/usr/bin/env python3
"""Checks the built book (mdbook build docs/book → target/book) as a reader
would meet it: every internal link and image of every page resolves to a
file of the built book, and every #anchor to an id on the page it names.

    check_book.py target/book

External links (with a scheme) are not followed. The study report under
study/ is the generated report, whose own links tools/check_report.py
checks; the book's links *into* it are checked here. A line per page; the
whole is one check, ending with `book check: 1 passed, 0 failed` (or 0, 1).
"""
import functools
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit


class Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.links, self.ids = [], set()

    def handle_starttag(self, tag, attrs):
        for k, v in attrs:
            if k == "id" and v:
                self.ids.add(v)
            if k in ("href", "src") and v:
                self.links.append(v)


@functools.cache
def parse(path):
    """The links of the page at `path` (each page read once)."""
    p = Page()
    p.feed(path.read_text(errors="replace"))
    return p


def main():
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    root = Path(sys.argv[1]).resolve()
    # 404.html is mdbook's own page, which resolves its links from the site's root (`<base href="/">`).
    pages = sorted(
        p for p in root.rglob("*.html") if "study" not in p.relative_to(root).parts and p.name != "404.html"
    )
    if len(pages) < 10:
        raise SystemExit(f"book check: only {len(pages)} pages under {root}: was the book built?")
    passed = failed = 0
    for page in pages:
        bad = []
        for link in parse(page).links:
            u = urlsplit(link)
            if u.scheme or link.startswith(("//", "mailto:")):
                continue
            target = page if not u.path else (page.parent / unquote(u.path)).resolve()
            if u.path.endswith("/") or target.is_dir():
                target = target / "index.html"
            if root not in target.parents and target != root:
                bad.append(f"{link} (outside the book)")
                continue
            if not target.is_file():
                bad.append(f"{link} (no such file)")
                continue
            if u.fragment and target.suffix == ".html" and unquote(u.fragment) not in parse(target).ids:
                bad.append(f"{link} (no id {u.fragment!r} on {target.relative_to(root)})")
        name = page.relative_to(root)
        if bad:
            failed += 1
            print(f"FAIL {name}: " + "; ".join(bad))
        else:
            passed += 1
            print(f"  ok   {name}: {len(parse(page).links)} links")
    print(f"{passed} of {len(pages)} pages' links and anchors resolve")
    print(f"book check: {int(not failed)} passed, {int(bool(failed))} failed")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
