#!/usr/bin/env python3
"""Lists the module import circles of every crate in the workspace (issue 39 item 5).

    python3 scripts/import_circles.py            # prints each circle; exits 1 when there is one
    python3 scripts/import_circles.py --quiet    # only the count

A module depends on another when its code names it: `use crate::a::b`, `use super::x`, or a
path such as `crate::a::f(...)` in an expression. Each dependency is read at the level of two
sibling modules: `crate::x::p` using `crate::y::q` is an edge `x → y` between the children of
their common parent. A module and its own ancestors are never a circle (a parent declares its
children; `use super::*` in a child is the usual shape), and test code (`#[cfg(test)]` items,
`tests/`, benches) is left out: a circle is a dependency of production code. A circle is a
strongly connected component of two or more siblings; each is printed with one name that ties
every edge.

Every crate root is followed through its `mod` declarations (`lib.rs`, `main.rs`, `src/bin/*`),
so a binary's modules are a crate of their own. Only the standard library.
"""

from __future__ import annotations

import argparse
import re
import sys
import tomllib
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"


def strip_comments_and_strings(text: str) -> str:
    """Blanks out comments, string and char literals (keeping line structure)."""
    out = []
    i, n = 0, len(text)
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
                    if text[i] == "\n":
                        out.append("\n")
                    i += 1
        elif c == "r" and re.match(r'r#*"', text[i:i + 260]) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            m = re.match(r'r(#*)"', text[i:])
            hashes = m.group(1)
            end = text.find('"' + hashes, i + len(m.group(0)))
            end = n if end < 0 else end + 1 + len(hashes)
            out.append('""' + "\n" * text.count("\n", i, end))
            i = end
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j + 1
        elif c == "'":
            m = re.match(r"'(\\.|[^\\'])'|'\\u\{[0-9a-fA-F]+\}'|'\\x[0-9a-fA-F]{2}'", text[i:])
            if m:
                out.append("' '")
                i += len(m.group(0))
            else:  # a lifetime
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def item_end(text: str, start: int) -> int:
    """The end of the item starting at `start`: its `;` or its balanced `{...}`."""
    depth = 0
    i = start
    while i < len(text):
        c = text[i]
        if c == "{":
            depth += 1
        elif c == "}":
            depth -= 1
            if depth == 0:
                return i + 1
        elif c == ";" and depth == 0:
            return i + 1
        i += 1
    return len(text)


def drop_test_items(text: str) -> str:
    """Removes every item under `#[cfg(test)]` (or `#[cfg(all(test, ...))]`)."""
    while True:
        m = re.search(r"#\[cfg\((all\()?test\b[^\]]*\]", text)
        if not m:
            return text
        j = m.end()
        # further attributes on the same item
        while True:
            a = re.match(r"\s*#\[[^\]]*\]", text[j:])
            if not a:
                break
            j += a.end()
        end = item_end(text, j)
        text = text[: m.start()] + "\n" * text.count("\n", m.start(), end) + text[end:]


def expand_use_tree(tree: str) -> list[str]:
    """`a::{b, c::{d, e}}` → [`a::b`, `a::c::d`, `a::c::e`]."""
    tree = re.sub(r"\s+", "", tree)
    if "{" not in tree:
        return [tree.split(" as ", 1)[0]]
    k = tree.index("{")
    prefix, inner = tree[:k], tree[k + 1 : tree.rindex("}")]
    parts, depth, cur = [], 0, ""
    for c in inner:
        if c == "," and depth == 0:
            parts.append(cur)
            cur = ""
            continue
        depth += c == "{"
        depth -= c == "}"
        cur += c
    parts.append(cur)
    out = []
    for p in parts:
        if p:
            out += [prefix + e if e != "self" else prefix.rstrip(":") for e in expand_use_tree(p)]
    return out


class Crate:
    def __init__(self, name: str) -> None:
        self.name = name
        self.modules: dict[tuple[str, ...], Path] = {}
        self.texts: dict[tuple[str, ...], str] = {}
        # inline modules (`mod x { ... }`) are part of their file's text
        self.inline: set[tuple[str, ...]] = set()


def load_module(crate: Crate, path: tuple[str, ...], file: Path, child_dir: Path) -> None:
    text = drop_test_items(strip_comments_and_strings(file.read_text()))
    crate.modules[path] = file
    crate.texts[path] = text
    for m in re.finditer(rf"^\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+({IDENT})\s*;", text, re.M):
        name = m.group(1)
        for cand in (child_dir / f"{name}.rs", child_dir / name / "mod.rs"):
            if cand.exists():
                sub_dir = child_dir / name
                load_module(crate, path + (name,), cand, sub_dir)
                break


def crate_roots(member: Path) -> list[tuple[str, Path]]:
    src = member / "src"
    roots = []
    for name in ("lib.rs", "main.rs"):
        if (src / name).exists():
            roots.append((name, src / name))
    for b in sorted((src / "bin").glob("*.rs")) if (src / "bin").is_dir() else []:
        roots.append((f"bin/{b.name}", b))
    return roots


def resolve(crate: Crate, here: tuple[str, ...], path: str) -> tuple[str, ...] | None:
    """The deepest module of the crate that `path` (as written in module `here`) names."""
    segs = [s for s in path.split("::") if s]
    if not segs:
        return None
    if segs[0] == "crate":
        base, rest = (), segs[1:]
    elif segs[0] in ("super", "self"):
        base = here
        rest = segs
        while rest and rest[0] in ("super", "self"):
            if rest[0] == "super":
                base = base[:-1]
            rest = rest[1:]
    else:
        return None
    mod = base
    for s in rest:
        if mod + (s,) in crate.modules:
            mod = mod + (s,)
        else:
            break
    return mod


def edges_of(crate: Crate) -> dict[tuple, dict[tuple, set[str]]]:
    """`(parent, a, b) → names`: sibling `a` under `parent` uses sibling `b` through `names`."""
    out: dict[tuple, dict[tuple, set[str]]] = defaultdict(lambda: defaultdict(set))
    for here, text in crate.texts.items():
        paths = []
        for m in re.finditer(r"\buse\s+([^;]+);", text):
            paths += expand_use_tree(m.group(1))
        paths += re.findall(rf"\b(?:crate|super)(?:::{IDENT})+", text)
        for p in paths:
            target = resolve(crate, here, p)
            if target is None or target == here:
                continue
            k = 0
            while k < min(len(here), len(target)) and here[k] == target[k]:
                k += 1
            if k == len(here) or k == len(target):
                continue  # an ancestor or a descendant
            parent = here[:k]
            name = p.split("::")[-1]
            out[parent][(here[k], target[k])].add(name)
    return out


def circles(edges: dict[tuple, set[str]]) -> list[list[str]]:
    graph: dict[str, set[str]] = defaultdict(set)
    for a, b in edges:
        graph[a].add(b)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def members() -> list[Path]:
    with (ROOT / "Cargo.toml").open("rb") as f:
        return [ROOT / m for m in tomllib.load(f)["workspace"]["members"]]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quiet", action="store_true", help="print only the count")
    a = ap.parse_args()
    total = 0
    for member in members():
        for root_name, root in crate_roots(member):
            crate = Crate(f"{member.relative_to(ROOT)} ({root_name})")
            load_module(crate, (), root, root.parent)
            for parent, edges in sorted(edges_of(crate).items()):
                for comp in circles(edges):
                    total += 1
                    if a.quiet:
                        continue
                    where = "::".join(("crate",) + parent)
                    print(f"{crate.name}: {where}: {' ↔ '.join(comp)}")
                    for (x, y), names in sorted(edges.items()):
                        if x in comp and y in comp:
                            print(f"    {x} → {y}: {', '.join(sorted(names))}")
    print(f"import circles: {total}")
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
