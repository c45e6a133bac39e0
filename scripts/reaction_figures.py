#!/usr/bin/env python3
"""Reaction figures over the run folders under a directory (scripts/reaction-bench.sh).

Reads each run's logs/rt-core.log (the cycle's event log) and pairs, as rt-core's own
meter does (rt-core/src/twin_thread/reaction.rs), each stop the scene caused with its
cause: a `PlanRevoked` (the twin's revocation, with the causing frame's capture and
acceptance times) followed by `StopBegun { reason: Revoked }` in the same cycle, or a
`CommandRefused` for clearance (with the capture time of the scene the shield checked)
followed by `StopBegun { reason: Shield(Clearance ..) }`. Prints the count and, in ms,
the median, p90 and max of capture -> changed command and acceptance -> changed command.
Fails (exit 1) when no reaction was found.
"""
import glob
import math
import re
import sys

EVENT = re.compile(r"t_s=([0-9.e+-]+) event=(.*)$")


def reactions(log_path):
    """(capture_ms, accepted_ms or None) for each reaction in one rt-core log."""
    out = []
    last_rev = last_ref = None
    with open(log_path, errors="replace") as f:
        for line in f:
            if "cycle event" not in line:
                continue
            m = EVENT.search(line)
            if not m:
                continue
            t = round(float(m.group(1)) * 1e9)
            ev = m.group(2)
            if ev.startswith("PlanRevoked"):
                cap = int(re.search(r"capture_ns: (\d+)", ev).group(1))
                acc = int(re.search(r"accepted_ns: (\d+)", ev).group(1))
                last_rev = (t, cap, acc)
            elif ev.startswith("CommandRefused") and "Clearance" in ev:
                last_ref = (t, int(re.search(r"scene_capture_ns: (\d+)", ev).group(1)), 0)
            elif ev.startswith("StopBegun { reason: Revoked") or ev.startswith(
                "StopBegun { reason: Shield(Clearance"
            ):
                cause = last_rev if "Revoked" in ev else last_ref
                if cause and abs(cause[0] - t) < 1000 and 0 < cause[1] <= t:
                    acc = (t - cause[2]) / 1e6 if 0 < cause[2] <= t else None
                    out.append(((t - cause[1]) / 1e6, acc))
                last_rev = last_ref = None
    return out


def quantile(values, q):
    v = sorted(values)
    return v[max(1, math.ceil(q * len(v))) - 1]


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else "runs/reaction-bench"
    # Each `foresight --out` folder also holds `latest`, a link to its newest run.
    logs = sorted(
        p
        for p in glob.glob(f"{root}/**/logs/rt-core.log", recursive=True)
        if "/latest/" not in p
    )
    found = [r for log in logs for r in reactions(log)]
    if not found:
        print(f"no reaction in {len(logs)} run(s) under {root}", file=sys.stderr)
        return 1
    cap = [c for c, _ in found]
    acc = [a for _, a in found if a is not None]
    print(f"{len(found)} reactions in {len(logs)} runs")
    for name, v in (("capture -> changed command", cap), ("accepted -> changed command", acc)):
        if v:
            # A p99 only from 100 samples: below, it would be the maximum under a new name.
            p99 = f"p99 {quantile(v, 0.99):.1f} ms, " if len(v) >= 100 else ""
            print(
                f"{name}: median {quantile(v, 0.5):.1f} ms, p90 {quantile(v, 0.9):.1f} ms, "
                f"{p99}max {max(v):.1f} ms (n = {len(v)})"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
