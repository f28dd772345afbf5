#!/usr/bin/env bash
# Take-over time of a server pool (docs/pool.md): runs the pool test N times on each record
# store and reports, per run, how long after the SIGKILL the four sessions of the dead server
# were claimed by the others (record clock) and resumed by their clients.
# Usage: tests/bench/bench_pool.sh [RUNS, default 3] [BUILD_DIR, default build/release]
set -euo pipefail
runs=${1:-3}
build=${2:-build/release}
bin="$build/tests/integration/telehand_integration"
[[ -x $bin ]] || { echo "bench_pool: no $bin (build the telehand_integration target)" >&2; exit 2; }
for store in sqlite postgresql; do
  for ((i = 1; i <= runs; i++)); do
    out=$("$bin" --gtest_filter="Store/PoolTest.*/$store" 2>&1) || {
      echo "$store run $i: FAILED"; echo "$out" | grep -E "Failure|Expected|actual" | head -5; continue; }
    line=$(echo "$out" | grep -E "^pool on" || true)
    echo "$store run $i (load $(cut -d' ' -f1 /proc/loadavg)): ${line#pool on $store: }"
  done
done
