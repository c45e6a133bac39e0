#!/usr/bin/env bash
# End-to-end reaction through the real processes (issue 33): runs the two moving worlds
# (assets/scenes/crossing_world.toml, stop_on_the_way_world.toml) N times each with the
# synthetic camera at 60 Hz, then prints, over every reaction rt-core logged, the time
# from the causing frame's capture (and from its acceptance by rt-core's intake) to the
# first changed command: median, p90, max and the count (scripts/reaction_figures.py).
# Usage: scripts/reaction-bench.sh <bin-dir> [runs per world, default 8] [out dir]
set -euo pipefail
bin=${1:?usage: reaction-bench.sh <bin-dir> [runs] [out]}
runs=${2:-8}
out=${3:-runs/reaction-bench}
cd "$(dirname "$0")/.."
mkdir -p "$out"
echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
failed=0
for i in $(seq 1 "$runs"); do
  for w in crossing_world stop_on_the_way_world; do
    # A failed run (goal missed, a contact) still logged its reactions: counted and kept.
    if ! "$bin/foresight" --world "assets/scenes/$w.toml" --out "$out/$w-$i" > "$out/$w-$i.log" 2>&1; then
      echo "run $w $i FAILED: $out/$w-$i.log" >&2
      failed=$((failed + 1))
    else
      echo "run $w $i done"
    fi
  done
done
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "runs failed: $failed of $((runs * 2))"
python3 scripts/reaction_figures.py "$out"
