#!/usr/bin/env python3
"""Checks the set-up's virtual environment the way pip would, with one stated exception.

torch is installed with --no-deps (scripts/setup.sh, step 2): Foresight uses only the libtorch
shared libraries inside the wheel (tch links them), never torch's Python module, so torch's
Python and CUDA requirements are deliberately absent. Every other installed package must have
exactly what it requires. Prints nothing and exits 0 when that holds; otherwise prints each
broken requirement, as `pip check` words it, and exits 1.

Usage: check_venv.py  (run by the venv's own python)
"""
import subprocess
import sys

# The distribution whose requirements the set-up leaves out on purpose (see the docstring).
LIBRARY_ONLY = "torch"


def main() -> int:
    out = subprocess.run(
        [sys.executable, "-m", "pip", "check"], capture_output=True, text=True, check=False
    )
    broken = [
        line
        for line in out.stdout.splitlines()
        if line.strip()
        and not line.lower().startswith(LIBRARY_ONLY + " ")
        and not line.startswith("No broken requirements")
    ]
    if out.returncode not in (0, 1) or out.stderr.strip():
        print(f"check_venv: pip check failed to run: {out.stderr.strip()}", file=sys.stderr)
        return 1
    for line in broken:
        print(f"check_venv: {line}", file=sys.stderr)
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
