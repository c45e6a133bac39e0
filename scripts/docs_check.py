#!/usr/bin/env python3
"""Keeps the README honest (issue 32 item 3): stale claims fail loudly.

    scripts/docs_check.py --bin DIR            # the checks `make test` runs (a few seconds)
    scripts/docs_check.py --bin DIR --rerun    # + re-run the deterministic figures (`make docs-check`)
    scripts/docs_check.py --write              # render docs/results.toml into README.md

Checks, each failure named with its file and line:
- README.md is at most 400 lines;
- README's results table (between `<!-- results:begin -->` and `<!-- results:end -->`) is the
  rendering of docs/results.toml, row for row;
- every relative link in README.md, ARCHITECTURE.md, docs/*.md and the crate READMEs
  (`rt-core/README.md`, `learner/README.md`, `perception/README.md`, any `<crate>/README.md`)
  points at a file that exists, and so does every repository path written in backticks there
  (`assets/...`, `rt-core/...`; in a crate README also the crate's own `src/...`, `tests/...`);
- every command of the results and of the code blocks of README.md and the crate READMEs
  exists: `make T` names a Makefile target, `BIN/x sub --flag` (and `foresight`/`make demo
  ARGS="--flag"`) names a binary, a subcommand and flags its `--help` lists (needs --bin: the
  release binaries);
- ARCHITECTURE.md's crate diagram names every workspace package;
- every crate's nearest clippy.toml (clippy reads the nearest one, it does not merge) carries
  the root clippy.toml's keys, and rt-core's and the sweep's carry the real-time bans
  (`RT_BANS`);
- with --rerun, each result with a `rerun` table is measured again and must give the same
  values (seeded, deterministic benchmarks; timings are dated instead).

Only the standard library (Python ≥ 3.11 for tomllib), so it runs before any venv exists.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
RESULTS = ROOT / "docs" / "results.toml"
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"
MAX_README_LINES = 400
# Top-level folders whose paths, written in backticks, must exist.
TREE = ("assets/", "scripts/", "rt-core/", "learner/", "perception/", "shm-schemas/", "tests/", "docs/", ".ci/")
# A crate README's own folders, whose paths in backticks must exist in the crate.
CRATE_TREE = ("src/", "tests/", "benches/")
# Binaries whose flags are checked against their --help.
BINARIES = {"foresight", "rt-core", "learner", "unseen-worlds", "perception", "xarm-sim", "zenoh-relay", "ros-bridge", "sweep"}


class Problems:
    def __init__(self) -> None:
        self.items: list[str] = []

    def add(self, where: str, what: str) -> None:
        self.items.append(f"{where}: {what}")


def load_results() -> list[dict]:
    with RESULTS.open("rb") as f:
        data = tomllib.load(f)
    rows = data.get("result", [])
    for i, r in enumerate(rows):
        for key in ("what", "target", "figure", "command", "date"):
            if not isinstance(r.get(key), str) or not r[key].strip():
                raise SystemExit(f"{RESULTS}: result {i + 1} has no `{key}` (a non-empty string)")
        if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", r["date"]):
            raise SystemExit(f"{RESULTS}: result {i + 1}: date {r['date']!r} is not YYYY-MM-DD")
    return rows


def render(rows: list[dict]) -> str:
    out = ["| what | target | measured | command | date |", "|---|---|---|---|---|"]
    for r in rows:
        figure = r["figure"] + (" (**not met**)" if r.get("met", True) is False else "")
        out.append(f"| {r['what']} | {r['target']} | {figure} | `{r['command']}` | {r['date']} |")
    return "\n".join(out)


def split_readme(text: str) -> tuple[str, str, str]:
    if BEGIN not in text or END not in text:
        raise SystemExit(f"README.md lacks the {BEGIN} / {END} markers")
    head, rest = text.split(BEGIN, 1)
    table, tail = rest.split(END, 1)
    return head, table.strip(), tail


def check_table(p: Problems, rows: list[dict]) -> None:
    _, table, _ = split_readme(README.read_text())
    want = render(rows)
    if table != want:
        got_lines, want_lines = table.splitlines(), want.splitlines()
        for i in range(max(len(got_lines), len(want_lines))):
            g = got_lines[i] if i < len(got_lines) else "<none>"
            w = want_lines[i] if i < len(want_lines) else "<none>"
            if g != w:
                p.add("README.md results table", f"row {i + 1} differs from docs/results.toml:\n  README:  {g}\n  results: {w}\n  (run scripts/docs_check.py --write)")
                break


def crate_dirs() -> list[Path]:
    """The workspace members' folders (and the excluded fuzz crate's)."""
    with (ROOT / "Cargo.toml").open("rb") as f:
        ws = tomllib.load(f)["workspace"]
    return [ROOT / m for m in ws["members"] + ws.get("exclude", [])]


def crate_readmes() -> list[Path]:
    return [d / "README.md" for d in crate_dirs() if d != ROOT and (d / "README.md").exists()]


def docs_files() -> list[Path]:
    return [README, ROOT / "ARCHITECTURE.md", *sorted((ROOT / "docs").glob("*.md")), *crate_readmes()]


def check_paths(p: Problems) -> None:
    for f in docs_files():
        in_code = False
        for n, line in enumerate(f.read_text().splitlines(), 1):
            if line.startswith("```"):
                in_code = not in_code
                continue
            where = f"{f.relative_to(ROOT)}:{n}"
            if not in_code:
                for target in re.findall(r"\]\(([^)\s]+)\)", line):
                    if re.match(r"^(https?:|mailto:|#)", target):
                        continue
                    path = (f.parent / target.split("#", 1)[0]).resolve()
                    if not path.exists():
                        p.add(where, f"link to {target}, which does not exist")
            in_crate = f in crate_readmes()
            for token in re.findall(r"`([^`\s]+)`", line):
                token = token.rstrip(".,:;")
                if any(c in token for c in "<>*…{}$|"):
                    continue
                if in_crate and token.startswith(CRATE_TREE):
                    # the crate's own `tests/…`, or the repository's `tests/` crate
                    if not ((f.parent / token).exists() or (token.startswith(TREE) and (ROOT / token).exists())):
                        p.add(where, f"`{token}` exists neither in {f.parent.relative_to(ROOT)}/ nor at the top")
                elif token.startswith(TREE):
                    if not (ROOT / token).exists():
                        p.add(where, f"`{token}` does not exist")


# The real-time bans each crate folder's clippy.toml must carry (issue 41 item 5): the runtime's,
# and the sweep's, which steps the runtime's worker and cycle on a manual clock.
RT_BANS = {
    "rt-core": {
        "disallowed-methods": {
            "std::time::Instant::now",
            "std::thread::sleep",
            "std::time::SystemTime::now",
            "xarm::driver::XArmDriver::send_servo",
            "xarm::driver::XArmDriver::read_state",
        },
        "disallowed-types": {"std::sync::Mutex", "std::sync::RwLock"},
    },
    "rt-core/sweep": {
        "disallowed-methods": {"std::time::Instant::now", "std::thread::sleep", "std::time::SystemTime::now"},
        "disallowed-types": {"std::sync::Mutex", "std::sync::RwLock"},
    },
}


def ban_paths(value) -> set[str]:
    return {v["path"] if isinstance(v, dict) else v for v in value}


def check_clippy_configs(p: Problems) -> None:
    """Clippy reads the nearest clippy.toml and does not merge: each crate's must repeat the
    root's keys (and the bans in its lists), and rt-core's and the sweep's carry `RT_BANS`."""
    with (ROOT / "clippy.toml").open("rb") as f:
        root = tomllib.load(f)
    for crate in crate_dirs():
        d = crate
        while d != ROOT and not (d / "clippy.toml").exists():
            d = d.parent
        nearest = d / "clippy.toml"
        where = f"{nearest.relative_to(ROOT)} (nearest to {crate.relative_to(ROOT) or '.'})"
        with nearest.open("rb") as f:
            cfg = tomllib.load(f)
        for key, want in root.items():
            if key not in cfg:
                p.add(where, f"lacks the root clippy.toml's `{key}`")
            elif isinstance(want, list):
                missing = ban_paths(want) - ban_paths(cfg[key])
                if missing:
                    p.add(where, f"`{key}` lacks the root's {sorted(missing)}")
            elif cfg[key] != want:
                p.add(where, f"`{key}` = {cfg[key]!r}, the root's is {want!r}")
        for key, want in RT_BANS.get(str(crate.relative_to(ROOT)), {}).items():
            if nearest.parent != crate:
                p.add(where, f"{crate.relative_to(ROOT)} needs a clippy.toml of its own with its bans")
                break
            missing = want - ban_paths(cfg.get(key, []))
            if missing:
                p.add(where, f"`{key}` lacks {sorted(missing)}")


def check_architecture_diagram(p: Problems) -> None:
    """ARCHITECTURE.md's first diagram names every workspace package."""
    text = (ROOT / "ARCHITECTURE.md").read_text()
    blocks = re.findall(r"(?ms)^```\n(.*?)^```", text)
    diagram = blocks[0] if blocks else ""
    with (ROOT / "Cargo.toml").open("rb") as f:
        members = tomllib.load(f)["workspace"]["members"]
    for m in members:
        with (ROOT / m / "Cargo.toml").open("rb") as f:
            name = tomllib.load(f)["package"]["name"]
        if not re.search(rf"(?<![\w-]){re.escape(name)}(?![\w-])", diagram):
            p.add("ARCHITECTURE.md", f"the crate diagram leaves out `{name}` ({m})")


def make_targets() -> set[str]:
    targets = set()
    for line in (ROOT / "Makefile").read_text().splitlines():
        m = re.match(r"^([A-Za-z0-9_.-]+)\s*:(?!=)", line)
        if m:
            targets.add(m.group(1))
    return targets


_help_cache: dict[tuple[str, ...], str | None] = {}


def help_text(bin_dir: Path, argv: tuple[str, ...]) -> str | None:
    if argv not in _help_cache:
        exe = bin_dir / argv[0]
        if not exe.exists():
            _help_cache[argv] = None
        else:
            r = subprocess.run([str(exe), *argv[1:], "--help"], capture_output=True, text=True, timeout=60)
            _help_cache[argv] = r.stdout + r.stderr if r.returncode == 0 else None
    return _help_cache[argv]


def check_command(p: Problems, where: str, command: str, bin_dir: Path | None, targets: set[str], usage: bool = False) -> None:
    """`usage`: a synopsis (`[--flag X]`, `a|b`), whose words are read without shell quoting."""
    if usage:
        words = re.sub(r"[\[\]|]", " ", command).split()
    else:
        try:
            words = shlex.split(command)
        except ValueError as e:
            p.add(where, f"cannot parse `{command}`: {e}")
            return
    if not words:
        return
    if words[0] == "make":
        rest = [w for w in words[1:] if "=" not in w]
        for t in rest:
            if t not in targets:
                p.add(where, f"`make {t}`: no such Makefile target")
        args = [w.split("=", 1)[1] for w in words[1:] if w.startswith("ARGS=")]
        if args and "demo" in rest:
            check_command(p, where, "BIN/foresight " + args[0], bin_dir, targets)
        return
    if words[0] == "bash" and len(words) > 1:
        if not (ROOT / words[1]).exists():
            p.add(where, f"`{words[1]}` does not exist")
        return
    name = words[0].removeprefix("BIN/")
    if name not in BINARIES or bin_dir is None:
        return
    argv = [name]
    flags = []
    for w in words[1:]:
        if w.startswith("--"):
            flags.append(w.split("=", 1)[0])
        elif not flags and re.fullmatch(r"[a-z][a-z-]*", w) and len(argv) < 3:
            # a subcommand, when the binary has it
            top = help_text(bin_dir, tuple(argv))
            if top is not None and re.search(rf"^\s+{re.escape(w)}\b", top, re.M):
                argv.append(w)
    text = help_text(bin_dir, tuple(argv))
    if text is None:
        p.add(where, f"`{' '.join(argv)} --help` failed: is `{name}` built in {bin_dir}?")
        return
    for flag in flags:
        if not re.search(rf"(^|[\s,]){re.escape(flag)}([\s=,<\[]|$)", text, re.M):
            p.add(where, f"`{' '.join(argv)}` has no flag {flag}")


def check_commands(p: Problems, rows: list[dict], bin_dir: Path | None) -> None:
    targets = make_targets()
    for i, r in enumerate(rows):
        check_command(p, f"docs/results.toml result {i + 1}", r["command"], bin_dir, targets)
    for f in [README, *crate_readmes()]:
        in_code = False
        # a crate README's `B=…/release/NAME` names the binary of its `$B …` synopsis lines
        binary, held, held_at = None, "", 0
        for n, line in enumerate(f.read_text().splitlines(), 1):
            if line.startswith("```"):
                in_code = not in_code
                binary = None
                continue
            if not in_code:
                continue
            command = line.split(" #", 1)[0].strip() if not line.lstrip().startswith("#") else ""
            if command.endswith("\\"):
                held, held_at = held + command[:-1] + " ", held_at or n
                continue
            command, at = held + command, held_at or n
            held, held_at = "", 0
            if m := re.match(r"^B=\S*/release/([a-z-]+)", command):
                binary = m.group(1)
                continue
            if binary and command.startswith("$B "):
                check_command(p, f"{f.relative_to(ROOT)}:{at}", binary + command[2:], bin_dir, targets, usage=True)
            elif command:
                check_command(p, f"{f.relative_to(ROOT)}:{at}", command, bin_dir, targets, usage=f != README)


def dig(value, dotted: str):
    """`a.b.2.c`: keys of objects, indices of lists."""
    for part in dotted.split("."):
        if isinstance(value, list) and part.isdigit() and int(part) < len(value):
            value = value[int(part)]
        elif isinstance(value, dict) and part in value:
            value = value[part]
        else:
            return KeyError(dotted)
    return value


def rerun(p: Problems, rows: list[dict], bin_dir: Path) -> None:
    for i, r in enumerate(rows):
        spec = r.get("rerun")
        if not spec:
            continue
        where = f"docs/results.toml result {i + 1} ({r['what'][:50]}…)"
        with tempfile.TemporaryDirectory(prefix="foresight-docs-check-") as tmp:
            command = spec["command"].replace("BIN/", f"{bin_dir}/").replace("{tmp}", tmp)
            print(f"docs-check: re-running {command}", file=sys.stderr, flush=True)
            run = subprocess.run(command, shell=True, cwd=ROOT, capture_output=True, text=True)
            if "file" in spec:
                path = Path(tmp) / spec["file"]
                if not path.exists():
                    p.add(where, f"`{command}` wrote no {spec['file']} (exit {run.returncode}): {run.stderr[-400:]}")
                    continue
                data = json.loads(path.read_text())
            else:
                objs = [l for l in run.stdout.splitlines() if l.startswith("{")]
                if not objs:
                    p.add(where, f"`{command}` printed no JSON (exit {run.returncode}): {run.stderr[-400:]}")
                    continue
                data = json.loads(objs[-1])
            for key, want in spec["expect"].items():
                got = dig(data, key)
                if isinstance(got, KeyError):
                    p.add(where, f"{key} is not in the output")
                elif got != want:
                    p.add(where, f"{key} is now {got!r}, the README says {want!r}: update docs/results.toml")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", type=Path, help="the release binaries (checks commands' flags)")
    ap.add_argument("--rerun", action="store_true", help="re-run the deterministic figures")
    ap.add_argument("--write", action="store_true", help="render docs/results.toml into README.md")
    a = ap.parse_args()
    rows = load_results()
    if a.write:
        head, _, tail = split_readme(README.read_text())
        README.write_text(f"{head}{BEGIN}\n{render(rows)}\n{END}{tail}")
        print("README.md: results table written")
    p = Problems()
    lines = len(README.read_text().splitlines())
    if lines > MAX_README_LINES:
        p.add("README.md", f"{lines} lines, more than {MAX_README_LINES}: move detail to docs/")
    check_table(p, rows)
    check_paths(p)
    check_clippy_configs(p)
    check_architecture_diagram(p)
    check_commands(p, rows, a.bin)
    if a.rerun:
        if a.bin is None:
            raise SystemExit("--rerun needs --bin")
        rerun(p, rows, a.bin)
    if p.items:
        print(f"docs-check: {len(p.items)} problem(s)", file=sys.stderr)
        for item in p.items:
            print(f"  {item}", file=sys.stderr)
        return 1
    print(f"docs-check: README.md ({lines} lines), {len(rows)} results, links, paths, commands and clippy.toml files OK" + (", figures re-run" if a.rerun else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
