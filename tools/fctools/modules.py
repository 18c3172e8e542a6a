"""The module graph of one Rust crate, from its sources: which of the
crate's top-level modules (the `mod`s of its `lib.rs`) name which others
(`crate::x…` in code, comments and strings apart), and the circles in it.
The crate root (`lib.rs`) is the hub every module may use and is left out,
and so is test code (a `tests.rs`, a `#[cfg(test)]` module), which may use
any module.
Read by tools/check_crates.py.
"""
import os
import re

MOD = re.compile(r"^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+([a-z_][a-z0-9_]*)\s*[;{]", re.MULTILINE)
PATH = re.compile(r"\bcrate::([a-z_][a-z0-9_]*)")
GROUP = re.compile(r"\bcrate::\{")


def code(text):
    """`text` without its comments, strings and char literals (a lifetime is kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            depth, i = 1, i + 2
            while i < n and depth:
                if text.startswith("/*", i):
                    depth, i = depth + 1, i + 2
                elif text.startswith("*/", i):
                    depth, i = depth - 1, i + 2
                else:
                    i += 1
        elif c == '"' or (c == "r" and re.match(r'r#*"', text[i:i + 4]) and not text[i - 1:i].isalnum()):
            m = re.match(r'r(#*)"', text[i:])
            if m:
                end = '"' + m.group(1)
                j = text.find(end, i + len(m.group(0)))
                i = n if j < 0 else j + len(end)
            else:
                i += 1
                while i < n and text[i] != '"':
                    i += 2 if text[i] == "\\" else 1
                i += 1
            out.append('""')
        elif c == "'" and re.match(r"'(\\.[^']*|[^\\'])'", text[i:]):
            i += len(re.match(r"'(\\.[^']*|[^\\'])'", text[i:]).group(0))
        else:
            out.append(c)
            i += 1
    return "".join(out)


TEST_MOD = re.compile(r"#\[cfg\(test\)\]\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+[a-z_][a-z0-9_]*\s*\{")


def without_tests(src):
    """`src` (as `code` gives it) without its `#[cfg(test)] mod … { … }` blocks."""
    while m := TEST_MOD.search(src):
        depth, j = 0, m.end() - 1
        while j < len(src):
            depth += {"{": 1, "}": -1}.get(src[j], 0)
            j += 1
            if depth == 0:
                break
        src = src[:m.start()] + src[j:]
    return src


def group_heads(src, at):
    """The first names inside a `crate::{…}` group opening at `at` (the brace)."""
    depth, j, heads, token = 0, at, [], True
    while j < len(src):
        ch = src[j]
        if ch == "{":
            depth += 1
            token = depth == 1
        elif ch == "}":
            depth -= 1
            if depth == 0:
                break
        elif ch == "," and depth == 1:
            token = True
        elif token and (ch.isalpha() or ch == "_"):
            m = re.match(r"[A-Za-z_][A-Za-z0-9_]*", src[j:])
            heads.append(m.group(0))
            j += len(m.group(0)) - 1
            token = False
        j += 1
    return heads


def top_modules(src_dir):
    """{module: [its files]} for the `mod`s `src_dir/lib.rs` declares."""
    with open(os.path.join(src_dir, "lib.rs")) as f:
        names = MOD.findall(code(f.read()))
    mods = {}
    for m in names:
        files = []
        single = os.path.join(src_dir, m + ".rs")
        if os.path.exists(single):
            files.append(single)
        tree = os.path.join(src_dir, m)
        for root, _, fs in os.walk(tree):
            files += [os.path.join(root, x) for x in fs if x.endswith(".rs") and x != "tests.rs"]
        mods[m] = sorted(files)
    return mods


def edges(src_dir):
    """{module: {modules it names}} among the crate's top-level modules."""
    mods = top_modules(src_dir)
    g = {m: set() for m in mods}
    for m, files in mods.items():
        for path in files:
            with open(path) as f:
                src = without_tests(code(f.read()))
            named = set(PATH.findall(src))
            for hit in GROUP.finditer(src):
                named.update(group_heads(src, hit.end() - 1))
            g[m] |= {x for x in named if x in mods and x != m}
    return g


def circles(g):
    """The strongly connected parts of `g` with more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(g[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                on.discard(w)
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                out.append(sorted(part))

    for v in sorted(g):
        if v not in index:
            visit(v)
    return out
