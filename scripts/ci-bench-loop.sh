#!/usr/bin/env bash
# Latency/jitter CI step (called by `make test` as `bash scripts/ci-bench-loop.sh <bin-dir>`).
# Runs `rt-core bench-loop` at 250 Hz and 1 kHz for a few seconds each, prints the JSON
# figures (so they can be followed over time), and fails only on gross faults:
#   - any allocation on the cycle thread,
#   - a missed-deadline ratio above MAX_MISSED_RATIO (default 1 %; 5 % at 1 kHz when the OS
#     refused SCHED_FIFO, i.e. the cycle competed with every other process on 2 cores),
#   - a deadlock (the harness's watchdog exits 3; a hard timeout here catches a hang),
#   - no cycles run at all.
# Latency percentiles are printed, never asserted: this is a shared, loaded, non-RT machine.
set -euo pipefail
bin_dir=${1:?usage: ci-bench-loop.sh <bin-dir>}
here=$(cd "$(dirname "$0")/.." && pwd)
exe="$bin_dir/rt-core"
seconds=${BENCH_SECONDS:-3}
max_missed=${MAX_MISSED_RATIO:-0.01}
# SCHED_FIFO is asked for; where the OS refuses it the bench says so and runs on.
rt_prio=${BENCH_RT_PRIORITY:-50}
[ -x "$exe" ] || { echo "ci-bench-loop: $exe not found (build with cargo build --release)" >&2; exit 1; }

fail=0
for rate in 250 1000; do
  out=$(timeout --kill-after=5 $((seconds + 30)) "$exe" bench-loop --rate "$rate" --seconds "$seconds" \
        --rt-priority "$rt_prio" --assets "$here/assets") || {
    rc=$?
    echo "ci-bench-loop: rate $rate Hz: bench-loop failed (exit $rc; 3 = watchdog, 124 = hang)" >&2
    echo "$out"
    fail=1
    continue
  }
  echo "bench-loop rate=$rate: $out"
  verdict=$(printf '%s' "$out" | python3 -c '
import json, sys
r = json.load(sys.stdin)
max_missed = float(sys.argv[1])
fifo = (r.get("rt_setup") or {}).get("fifo") or {}
if r["rate_hz"] > 500 and "Ok" not in fifo:
    max_missed = max(max_missed, 0.05)
bad = []
if r["cycles"] <= 0: bad.append("no cycles ran")
if r["allocations_in_cycle"] != 0: bad.append("%d allocations in the cycle" % r["allocations_in_cycle"])
if r["missed_ratio"] > max_missed: bad.append("missed-deadline ratio %.4f > %.4f" % (r["missed_ratio"], max_missed))
w, c = r["wakeup_latency_us"], r["cycle_compute_us"]
print("  rate %g Hz: %d cycles, missed %d, allocs %d | wake-up p50 %.0f p99 %.0f p99.9 %.0f max %.0f us | compute p50 %.0f p99 %.0f p99.9 %.0f max %.0f us | swaps %d, plans taken %d, lookahead p50 %.2f ms" % (
    r["rate_hz"], r["cycles"], r["missed_deadlines"], r["allocations_in_cycle"],
    w["p50_us"], w["p99_us"], w["p999_us"], w["max_us"], c["p50_us"], c["p99_us"], c["p999_us"], c["max_us"],
    r["policy_swaps"], r["plans_taken_by_cycle"], r["lookahead_ms"]["p50"]), file=sys.stderr)
print("; ".join(bad) if bad else "ok")
' "$max_missed")
  if [ "$verdict" != "ok" ]; then
    echo "ci-bench-loop: rate $rate Hz: FAIL: $verdict" >&2
    fail=1
  fi
done
exit $fail
