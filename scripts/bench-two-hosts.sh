#!/usr/bin/env bash
# World change → motion on one host and across two (issue 16's target: the two-host figure
# within 10 % of the one-host figure). Runs the demo's fast world N times each way,
# alternating, and prints the medians of `world_change_to_motion_s` and `retrain_s` from
# each run's summary.json. Two hosts = two network namespaces joined by a veth pair (needs
# root); the learner side runs `zenoh-relay learner-host`. Usage: scripts/bench-two-hosts.sh [N]
set -euo pipefail
cd "$(dirname "$0")/.."
n=${1:-5}
bin=${BIN:-$(scripts/cargo.sh metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')/release}
out=$(mktemp -d /tmp/fs-two-hosts-bench.XXXXXX)
r=fsbr$$; l=fsbl$$
cleanup() { ip netns del "$r" 2>/dev/null || true; ip netns del "$l" 2>/dev/null || true; }
trap cleanup EXIT
ip netns add "$r"; ip netns add "$l"
ip link add "${r}v" type veth peer name "${l}v"
ip link set "${r}v" netns "$r"; ip link set "${l}v" netns "$l"
ip -n "$r" addr add 10.233.0.1/24 dev "${r}v"; ip -n "$l" addr add 10.233.0.2/24 dev "${l}v"
for ns in "$r" "$l"; do ip -n "$ns" link set lo up; done
ip -n "$r" link set "${r}v" up; ip -n "$l" link set "${l}v" up
"$bin/zenoh-relay" keygen --out "$out/keys" > /dev/null  # the link's keys (issue 25)
common=(--world assets/scenes/fast_world.toml --phase-timeout-s 60 --retrain-budget-s 40)
for i in $(seq 1 "$n"); do
  "$bin/foresight" "${common[@]}" --out "$out/one/$i" > /dev/null 2>&1 || echo "one-host run $i failed"
  # A fresh learner host per run, as the one-host run starts a fresh learner: a learner host
  # that stays up resumes from its last converged policy and retrains the next run faster.
  ip netns exec "$l" "$bin/zenoh-relay" learner-host --listen tcp/10.233.0.2:7447 \
    --link-keys "$out/keys/learner-host" --out "$out/learner-runs/$i" --time-budget-s 40 > "$out/learner-host-$i.log" 2>&1 &
  lh=$!
  ip netns exec "$r" "$bin/foresight" "${common[@]}" --learner-host --peer tcp/10.233.0.2:7447 \
    --link-keys "$out/keys/robot-pc" --out "$out/two/$i" > /dev/null 2>&1 || echo "two-host run $i failed"
  kill "$lh" 2>/dev/null || true; wait "$lh" 2>/dev/null || true
done
python3 - "$out" <<'PY'
import glob, json, os, statistics, sys
out = sys.argv[1]
for way in ("one", "two"):
    rows = []
    for f in sorted(glob.glob(f"{out}/{way}/*/*/summary.json")):
        if os.path.islink(os.path.dirname(f)):
            continue  # runs/latest
        s = json.load(open(f))
        rows.append((s.get("world_change_to_motion_s"), s.get("retrain_s"), s["goal_reached"], s["collisions"]))
    motion = [m for m, _, _, _ in rows if m is not None]
    retrain = [t for _, t, _, _ in rows if t is not None]
    ok = sum(1 for r in rows if r[2] and r[3] == 0)
    med = lambda v: f"{statistics.median(v):.2f} s" if v else "n/a"
    print(f"{way} host{'s' if way == 'two' else ''}: {len(rows)} runs, {ok} reached with 0 collisions; "
          f"world change → motion median {med(motion)} {[round(m, 2) for m in motion]}; retraining median {med(retrain)}")
PY
echo "runs in $out"
