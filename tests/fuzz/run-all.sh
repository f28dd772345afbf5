#!/usr/bin/env bash
# Runs every fuzz target for RUNS inputs (default 1,000,000), at most MAX_SECONDS each
# (default 600), and prints runs, time, exec/s and the outcome per target.
#   tests/fuzz/run-all.sh [RUNS] [MAX_SECONDS]   (BUILD=build/release by default)
# New inputs go to a scratch corpus under $WORK (default /tmp/telehand-fuzz); the seeds in
# tests/fuzz/corpus stay untouched; crashes are written to $WORK/<target>/crash-*.
set -u
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../.." && pwd)
runs=${1:-1000000}
max_s=${2:-600}
build=${BUILD:-$root/build/release}
work=${WORK:-/tmp/telehand-fuzz}
targets="fuzz_mf2_decoder fuzz_wire_joint_model fuzz_wire_knn_model fuzz_wire_device_state
fuzz_wire_record_chunk fuzz_wire_hand_state fuzz_wire_direct_force fuzz_config_client
fuzz_config_server fuzz_config_patient_case fuzz_mf2_device_file fuzz_link_profile
fuzz_secured_submessage"
status=0
printf '%-26s %10s %8s %8s  %s\n' target runs seconds exec/s outcome
for t in $targets; do
  bin=$build/tests/fuzz/$t
  [ -x "$bin" ] || { printf '%-26s %s\n' "$t" "not built"; status=1; continue; }
  seeds=$here/corpus/$t
  [ "$t" = fuzz_mf2_decoder ] && seeds=$here/corpus
  [ -d "$seeds" ] || seeds=
  mkdir -p "$work/$t/corpus"
  log=$work/$t.log
  start=$(date +%s.%N)
  (cd "$work/$t" && "$bin" -runs="$runs" -max_total_time="$max_s" -seed=1 -max_len=16384 \
      -print_final_stats=1 "$work/$t/corpus" $seeds) > "$log" 2>&1 <<< "" ||
    true
  rc=${PIPESTATUS[0]}
  end=$(date +%s.%N)
  done_runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$')
  secs=$(echo "$end - $start" | bc)
  eps=$(grep -o 'stat::average_exec_per_sec: *[0-9]*' "$log" | grep -o '[0-9]*$')
  if grep -q 'ERROR\|SUMMARY\|deadly\|crash-' "$log"; then
    outcome="FOUND ($(grep -m1 -o 'SUMMARY.*\|ERROR: [^(]*' "$log")), see $log"
    status=1
  elif [ "${done_runs:-0}" -ge "$runs" ]; then
    outcome=clean
  else
    outcome="clean, time bound reached"
  fi
  printf '%-26s %10s %8.1f %8s  %s\n' "$t" "${done_runs:-?}" "$secs" "${eps:-?}" "$outcome"
done
exit $status
