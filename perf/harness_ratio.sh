#!/usr/bin/env bash
# What fringe's own harness costs beside what it measures, each figure a ratio taken in one
# run of this script (the machine's load moves both sides alike):
#   1. `fringe run fixtures/scenarios/perf-1e7.json --no-db` (10^7 samples, ekf-diffraction +
#      atan2, scored, reports built) against ekf-diffraction CV alone over 10^7 samples of the
#      same signal (bench_estimators ekf_diffraction_cv_perf1e7);
#   2. the same scenario with atan2 alone (perf-1e7-atan2.json) against the generator's own
#      time for those 10^7 samples (bench_signal_gen BM_perf_1e7).
# Usage: perf/harness_ratio.sh [BUILD_DIR] [REPETITIONS] ; medians of the repetitions.
set -euo pipefail
build="${1:-build}"
reps="${2:-3}"
src="$(cd "$(dirname "$0")/.." && pwd)"
py=/usr/bin/python3
median() { tr ' ' '\n' | sort -g | awk '{a[NR]=$1} END{print a[int((NR+1)/2)]}'; }
# items_per_second of one benchmark, median of the repetitions
bench_rate() {
  "$1" --benchmark_filter="$2" --benchmark_repetitions="$reps" --benchmark_format=json 2>/dev/null |
    "$py" -c 'import json,sys,statistics; b=[x for x in json.load(sys.stdin)["benchmarks"] if x.get("run_type")=="iteration"]; print(statistics.median(x["items_per_second"] for x in b))'
}
wall() {  # median wall seconds of a command over the repetitions
  local ts=()
  for _ in $(seq "$reps"); do
    local t0 t1
    t0=$(date +%s.%N); "$@" >/dev/null; t1=$(date +%s.%N)
    ts+=("$(echo "$t1 - $t0" | bc -l)")
  done
  echo "${ts[*]}" | median
}
n=10000000
ekf_rate=$(bench_rate "$build/perf/bench_estimators" 'ekf_diffraction_cv_perf1e7$')
gen_rate=$(bench_rate "$build/perf/bench_signal_gen" 'BM_perf_1e7/65536$')
run_s=$(wall "$build/server/fringe" run "$src/fixtures/scenarios/perf-1e7.json" --no-db -q)
atan2_s=$(wall "$build/server/fringe" run "$src/fixtures/scenarios/perf-1e7-atan2.json" --no-db -q)
"$py" - "$n" "$ekf_rate" "$gen_rate" "$run_s" "$atan2_s" "$(nproc)" "$(cut -d' ' -f1 /proc/loadavg)" <<'PY'
import sys
n, ekf_rate, gen_rate, run_s, atan2_s = (float(x) for x in sys.argv[1:6])
ekf_s, gen_s = n / ekf_rate, n / gen_rate
print(f"machine: {sys.argv[6]} hardware threads, load {sys.argv[7]}")
print(f"ekf-diffraction CV alone, 10^7 samples: {ekf_s:.3f} s ({ekf_rate/1e6:.1f} M/s)")
print(f"fringe run perf-1e7.json --no-db:       {run_s:.3f} s  ratio {run_s/ekf_s:.2f} (target <= 1.2)")
print(f"generator alone, 10^7 samples:          {gen_s:.3f} s ({gen_rate/1e6:.1f} M pairs/s)")
print(f"fringe run perf-1e7-atan2.json --no-db: {atan2_s:.3f} s  ratio {atan2_s/gen_s:.2f} (target <= 2.5)")
PY
