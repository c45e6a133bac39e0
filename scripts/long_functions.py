#!/usr/bin/env python3
"""Lists the functions longer than a limit (issue 39: at most 80 lines), production code only.

    python3 scripts/long_functions.py            # every function over 80 lines, longest first
    python3 scripts/long_functions.py --under rt-core/src --limit 80

A function's length is the lines from its `fn` to its closing brace. Left out: test code
(`#[cfg(test)]` items and `tests.rs` modules, `tests/`, `benches/`, `examples/` and the fuzz targets; the system
tests' rig in `tests/src` counts). Only the standard library.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from import_circles import ROOT, drop_test_items, strip_comments_and_strings  # noqa: E402


def lengths(under: str) -> list[tuple[int, str, str]]:
    files = subprocess.run(["git", "ls-files", "*.rs"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    out = []
    for f in files:
        if not f.startswith(under):
            continue
        if f.endswith("/tests.rs") or (re.search(r"(^|/)(tests|benches|examples|fuzz)/", f) and not f.startswith(("tests/src/", "tests/worldgen/src/"))):
            continue
        text = drop_test_items(strip_comments_and_strings((ROOT / f).read_text()))
        for m in re.finditer(r"\bfn\s+(\w+)[^;{]*\{", text):
            depth, j = 0, m.end() - 1
            while j < len(text):
                depth += {"{": 1, "}": -1}.get(text[j], 0)
                if depth == 0:
                    break
                j += 1
            first = text.count("\n", 0, m.start()) + 1
            out.append((text.count("\n", 0, j) + 2 - first, f"{f}:{first}", m.group(1)))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--under", default="", help="a folder (default: the whole workspace)")
    ap.add_argument("--limit", type=int, default=80, help="longest allowed, lines")
    a = ap.parse_args()
    long = sorted((x for x in lengths(a.under) if x[0] > a.limit), reverse=True)
    for n, where, name in long:
        print(f"{n:4} {where} {name}")
    print(f"functions over {a.limit} lines{' under ' + a.under if a.under else ''}: {len(long)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
