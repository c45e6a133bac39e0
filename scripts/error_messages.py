#!/usr/bin/env python3
"""Fails when an error message prints a source it also returns (issue 39 item 7).

    python3 scripts/error_messages.py     # run by `make lint`

A thiserror message says what failed; its cause is the error's `source()`, and whoever logs or
prints the error shows the whole chain (`shm_schemas::error_chain`, anyhow's `{:#}`). A message
that also formats the source (`{0}`, `{source}`, `.0.message`, ... beside `#[source]`/`#[from]`,
or a field named `source`) prints the cause twice in every chain. Checked: every `#[error(...)]`
of the workspace's Rust files (tests included), against the fields of the variant or struct it
stands on. `#[error(transparent)]` is fine: it forwards both. Only the standard library.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def closing(text: str, i: int) -> int:
    """Index just past the bracket closing the one at `i`, skipping strings and chars."""
    pairs = {"(": ")", "[": "]", "{": "}"}
    stack, j = [pairs[text[i]]], i + 1
    while stack and j < len(text):
        c = text[j]
        if c == '"':
            j += 1
            while j < len(text) and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
        elif c == "'" and re.match(r"'(\\.|[^\\'])'", text[j : j + 4]):
            j = text.index("'", j + 2)
        elif c in pairs:
            stack.append(pairs[c])
        elif c == stack[-1]:
            stack.pop()
        j += 1
    return j


def item_fields(text: str, i: int) -> str:
    """The field list `(...)` or `{...}` of the variant or struct that starts at `i` (after its
    attributes and doc comments); empty for a unit variant."""
    while True:
        m = re.match(r"\s*(//[^\n]*\n|#\[)", text[i:])
        if not m:
            break
        i += m.end()
        if m.group(1) == "#[":
            i = closing(text, i - 1)
    m = re.match(r"\s*(pub(\([^)]*\))?\s+)?(struct\s+|enum\s+)?\w+(<[^>{(]*>)?\s*", text[i:])
    if not m:
        return ""
    j = i + m.end()
    if j < len(text) and text[j] in "({":
        return text[j : closing(text, j)]
    return ""


def source_names(fields: str) -> list[str]:
    """How a message would name the source field: `0` for a tuple field, else its name."""
    names = []
    if fields.startswith("("):
        for k, f in enumerate(split_top(fields[1:-1])):
            if re.search(r"#\[(source|from)\]", f):
                names.append(str(k))
    else:
        for f in split_top(fields[1:-1]):
            m = re.search(r"(\w+)\s*:", re.sub(r"(///[^\n]*|#\[[^\]]*\])", "", f))
            if m and (re.search(r"#\[(source|from)\]", f) or m.group(1) == "source"):
                names.append(m.group(1))
    return names


def split_top(s: str) -> list[str]:
    """`s` split at its top-level commas."""
    out, depth, cur = [], 0, ""
    for c in s:
        depth += c in "([{<"
        depth -= c in ")]}>"
        if c == "," and depth == 0:
            out.append(cur)
            cur = ""
        else:
            cur += c
    return out + [cur] if cur.strip() else out


def problems(path: str, text: str) -> list[str]:
    out = []
    for m in re.finditer(r"#\[error\(", text):
        end = closing(text, m.end() - 1)
        args = text[m.end() : end - 1]
        if args.strip() == "transparent":
            continue
        for name in source_names(item_fields(text, end + 1)):
            shown = re.search(r"\{" + name + r"(:[^}]*)?\}", args) or re.search(r"\.\s*" + name + r"\b", args)
            if shown:
                line = text.count("\n", 0, m.start()) + 1
                out.append(f"{path}:{line}: the message formats its source `{name}` ({shown.group(0)}); "
                           "say what failed and let the chain print the cause")
    return out


def main() -> int:
    files = subprocess.run(["git", "ls-files", "*.rs"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    found = [p for f in files for p in problems(f, (ROOT / f).read_text())]
    for p in found:
        print(p)
    print(f"error messages that print their own source: {len(found)}")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
