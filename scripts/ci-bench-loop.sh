#!/usr/bin/env bash
# Latency/jitter CI step (called by `make test` as `bash scripts/ci-bench-loop.sh <bin-dir>`).
# Runs `rt-core bench-loop` at 250 Hz and 1 kHz for BENCH_CYCLES cycles each (default 10 000:
# a p99.9 needs well over 1 000 samples; 40 s and 10 s), prints the JSON
# figures (so they can be followed over time), and fails only on faults of the cycle itself:
#   - any allocation on the cycle thread,
#   - a compute-overrun ratio above MAX_OVERRUN_RATIO (default 1 %): cycles whose own
#     compute took longer than the period — the cycle's code answers for those,
#   - a deadlock (the harness's watchdog exits 3; a hard timeout here catches a hang),
#   - no cycles run at all.
# The missed-deadline ratio (late wake-ups included) is printed with what the machine did
# meanwhile (CPU steal, cgroup throttling) and gated (MAX_MISSED_RATIO, default 1 %) only with
# BENCH_STRICT_RT=1, i.e. on a host that gives the cycle an isolated core. Decision: on a
# shared CI VM a late wake-up is the scheduler's, not the cycle's — a CI run once saw wake-up
# p99 11 ms and 9 % missed deadlines at 250 Hz with compute p99 0.3 ms, and no code change
# of ours could have fixed that. Latency percentiles are printed, never asserted.
set -euo pipefail
bin_dir=${1:?usage: ci-bench-loop.sh <bin-dir>}
here=$(cd "$(dirname "$0")/.." && pwd)
exe="$bin_dir/rt-core"
cycles=${BENCH_CYCLES:-10000}
max_missed=${MAX_MISSED_RATIO:-0.01}
max_overrun=${MAX_OVERRUN_RATIO:-0.01}
strict=${BENCH_STRICT_RT:-0}
# SCHED_FIFO is asked for; where the OS refuses it the bench says so and runs on.
rt_prio=${BENCH_RT_PRIORITY:-50}
[ -x "$exe" ] || { echo "ci-bench-loop: $exe not found (build with cargo build --release)" >&2; exit 1; }

# What the machine took from us during a run: steal jiffies (all CPUs, /proc/stat) and
# cgroup v2 throttling (periods, µs). Printed as "steal_jiffies throttled_periods throttled_us".
machine_counters() {
  local steal throttled=0 throttled_us=0
  steal=$(awk '/^cpu /{print $9; exit}' /proc/stat 2>/dev/null || echo 0)
  if [ -r /sys/fs/cgroup/cpu.stat ]; then
    throttled=$(awk '$1=="nr_throttled"{print $2}' /sys/fs/cgroup/cpu.stat)
    throttled_us=$(awk '$1=="throttled_usec"{print $2}' /sys/fs/cgroup/cpu.stat)
  fi
  echo "${steal:-0} ${throttled:-0} ${throttled_us:-0}"
}

fail=0
for rate in 250 1000; do
  # Whole seconds covering `cycles` periods (BENCH_SECONDS overrides, for a quick look).
  seconds=${BENCH_SECONDS:-$(( (cycles + rate - 1) / rate ))}
  before=$(machine_counters)
  out=$(timeout --kill-after=5 $((seconds + 30)) "$exe" bench-loop --rate "$rate" --seconds "$seconds" \
        --rt-priority "$rt_prio" --assets "$here/assets") || {
    rc=$?
    echo "ci-bench-loop: rate $rate Hz: bench-loop failed (exit $rc; 3 = watchdog, 124 = hang)" >&2
    echo "$out"
    fail=1
    continue
  }
  after=$(machine_counters)
  echo "bench-loop rate=$rate: $out"
  verdict=$(printf '%s' "$out" | python3 -c '
import json, sys
r = json.load(sys.stdin)
max_missed, max_overrun, strict = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3] == "1"
b, a = [int(x) for x in sys.argv[4].split()], [int(x) for x in sys.argv[5].split()]
steal, thr, thr_us = a[0] - b[0], a[1] - b[1], a[2] - b[2]
bad = []
if r["cycles"] <= 0: bad.append("no cycles ran")
if r["allocations_in_cycle"] != 0: bad.append("%d allocations in the cycle" % r["allocations_in_cycle"])
if r["compute_overrun_ratio"] > max_overrun:
    bad.append("compute-overrun ratio %.4f > %.4f" % (r["compute_overrun_ratio"], max_overrun))
if strict and r["missed_ratio"] > max_missed:
    bad.append("missed-deadline ratio %.4f > %.4f (BENCH_STRICT_RT=1)" % (r["missed_ratio"], max_missed))
w, c = r["wakeup_latency_us"], r["cycle_compute_us"]
print("  rate %g Hz: %d cycles, missed %d (%.2f %%%s), compute overruns %d, allocs %d | wake-up p50 %.0f p99 %.0f p99.9 %.0f max %.0f us | compute p50 %.0f p99 %.0f p99.9 %.0f max %.0f us | swaps %d, plans taken %d, lookahead p50 %.2f ms | machine: steal %d jiffies, cgroup throttled %d periods (%d us)" % (
    r["rate_hz"], r["cycles"], r["missed_deadlines"], 100 * r["missed_ratio"], "" if strict else ", not gated",
    r["compute_overruns"], r["allocations_in_cycle"],
    w["p50_us"], w["p99_us"], w["p999_us"], w["max_us"], c["p50_us"], c["p99_us"], c["p999_us"], c["max_us"],
    r["policy_swaps"], r["plans_taken_by_cycle"], r["lookahead_ms"]["p50"], steal, thr, thr_us), file=sys.stderr)
print("; ".join(bad) if bad else "ok")
' "$max_missed" "$max_overrun" "$strict" "$before" "$after")
  if [ "$verdict" != "ok" ]; then
    echo "ci-bench-loop: rate $rate Hz: FAIL: $verdict" >&2
    fail=1
  fi
done
exit $fail
