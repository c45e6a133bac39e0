#!/usr/bin/env python3
"""Rust functions longer than N lines, per crate or path (issue 39).

A function's length counts its lines from the line holding `fn` to the line of its closing
brace, both included (attributes and doc comments above it are not counted). Functions in
test code count like any other; declarations without a body (`fn f();` in a trait) are
skipped.

    scripts/fn_lengths.py rt-core/src                 # every function over 80 lines there
    scripts/fn_lengths.py --max 50 rt-core/src/twin_thread
    scripts/fn_lengths.py --summary .                 # counts per crate over 80 lines
    scripts/fn_lengths.py --check rt-core/src         # exit 1 when any is over the limit

Paths are files or folders (searched for `*.rs`, skipping `target/` and hidden folders).
The parser is a small lexer, not a Rust parser: it skips strings, raw strings, chars,
lifetimes and comments, and matches braces; good enough for rustfmt-formatted code.
"""

import argparse
import os
import re
import sys
from collections import Counter

FN_RE = re.compile(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)")


def strip_code(text):
    """The text with comments, strings and char literals blanked (newlines kept), so that
    braces and `fn` are only found in code."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        nxt = text[i + 1] if i + 1 < n else ""
        if c == "/" and nxt == "/":
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif c == "/" and nxt == "*":
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "r" and re.match(r'r#*"', text[i:i + 10]) and not _ident_char(text, i - 1):
            m = re.match(r'r(#*)"', text[i:])
            end = '"' + m.group(1)
            j = text.find(end, i + len(m.group(0)))
            j = n if j < 0 else j + len(end)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            j = min(j + 1, n)
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == "'":
            # A char literal ('a', '\n', '\u{..}') or a lifetime ('a): only the former is blanked.
            m = re.match(r"'(\\.[^']*|[^\\'])'", text[i:i + 12])
            if m:
                out.append(" " * len(m.group(0)))
                i += len(m.group(0))
            else:
                out.append(c)
                i += 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def _ident_char(text, i):
    return i >= 0 and (text[i].isalnum() or text[i] == "_")


def functions(path):
    """(name, first line, length in lines) of every function with a body in `path`."""
    with open(path, encoding="utf-8") as f:
        code = strip_code(f.read())
    found = []
    for m in FN_RE.finditer(code):
        # The body starts at the first `{` after the signature, unless a `;` comes first.
        depth_paren, j = 0, m.end()
        while j < len(code):
            ch = code[j]
            if ch in "([<":
                depth_paren += 1
            elif ch in ")]>":
                depth_paren -= 1 if ch != ">" or code[j - 1] != "-" else 0
            elif ch == ";" and depth_paren <= 0:
                j = -1
                break
            elif ch == "{" and depth_paren <= 0:
                break
            j += 1
        if j < 0 or j >= len(code):
            continue
        depth, k = 0, j
        while k < len(code):
            if code[k] == "{":
                depth += 1
            elif code[k] == "}":
                depth -= 1
                if depth == 0:
                    break
            k += 1
        first = code.count("\n", 0, m.start()) + 1
        last = code.count("\n", 0, k) + 1
        found.append((m.group(1), first, last - first + 1))
    return found


def rust_files(paths):
    for p in paths:
        if os.path.isfile(p):
            yield p
            continue
        for root, dirs, files in os.walk(p):
            dirs[:] = sorted(d for d in dirs if d != "target" and not d.startswith("."))
            for name in sorted(files):
                if name.endswith(".rs"):
                    yield os.path.join(root, name)


def crate_of(path):
    """The folder of the nearest Cargo.toml above `path` (the crate), relative."""
    d = os.path.dirname(os.path.abspath(path))
    while d != os.path.dirname(d):
        if os.path.exists(os.path.join(d, "Cargo.toml")):
            return os.path.relpath(d) or "."
        d = os.path.dirname(d)
    return "?"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("paths", nargs="*", default=["."])
    ap.add_argument("--max", type=int, default=80, help="longest allowed, lines (80)")
    ap.add_argument("--summary", action="store_true", help="counts per crate only")
    ap.add_argument("--check", action="store_true", help="exit 1 when any is over --max")
    args = ap.parse_args()
    over = []
    for path in rust_files(args.paths):
        for name, line, length in functions(path):
            if length > args.max:
                over.append((length, path, line, name))
    over.sort(key=lambda o: (-o[0], o[1], o[2]))
    if args.summary:
        per_crate = Counter(crate_of(p) for _, p, _, _ in over)
        for crate, count in sorted(per_crate.items(), key=lambda kv: (-kv[1], kv[0])):
            print(f"{count:4}  {crate}")
    else:
        for length, path, line, name in over:
            print(f"{length:5}  {path}:{line}  {name}")
    print(f"{len(over)} function(s) over {args.max} lines in {' '.join(args.paths)}")
    return 1 if args.check and over else 0


if __name__ == "__main__":
    sys.exit(main())
