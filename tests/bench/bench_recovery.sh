#!/usr/bin/env bash
# What a server's death costs the student's haptic loop (docs/recovery.md "Measured"): the
# same telehand-server + telehand-client session on loopback, interleaved
#   none  nothing happens to the server;
#   kill  the server is killed (SIGKILL) at KILL_AT s and started again on the same record
#         at RESTART_AT s;
#   term  the same with SIGTERM;
# and, per round and as medians per mode, the client's loop overruns and worst wake-up, the
# samples it sent, what its record says is missing, and its exit code.
# The server runs on the client's machine here, so its restart (a Bullet hand, the record
# read back, the client's backlog stored) competes with the loop for the same cores, where a
# real server is elsewhere; RT_PRIORITY=N runs the client's loop at SCHED_FIFO N (needs
# CAP_SYS_NICE), as a device PC would; PIN=1 keeps the server on the last CPU and the client
# on the others (taskset), as a server on another machine would be. Together they tell the
# server's work apart from what the outage costs the client itself.
# Usage: tests/bench/bench_recovery.sh [ROUNDS (default 3)] [SECONDS per session (default 20)]
#        KILL_AT (default 5), RESTART_AT (default 10), RT_PRIORITY and PIN from the environment.
set -euo pipefail
cd "$(dirname "$0")/../.."
rounds=${1:-3}
seconds=${2:-20}
kill_at=${KILL_AT:-5}
restart_at=${RESTART_AT:-10}
bin=build/release
for p in "$bin/server/telehand-server" "$bin/client/telehand-client"; do
  [ -x "$p" ] || { echo "bench_recovery: no $p (build first: deploy/build.sh release)" >&2; exit 2; }
done
awk -v s="$seconds" -v k="$kill_at" -v r="$restart_at" 'BEGIN{exit !(k > 0 && r > k && s > r + 2)}' || {
  echo "bench_recovery: need 0 < KILL_AT < RESTART_AT < SECONDS - 2 (got $kill_at, $restart_at, $seconds)" >&2
  exit 2
}
work=$(mktemp -d /tmp/telehand-bench-recovery-XXXXXX)
server=
trap '[ -n "$server" ] && kill "$server" 2>/dev/null; wait 2>/dev/null || true; rm -rf "$work"' EXIT
net=(--dds-config deploy/cyclonedds/loopback.xml --insecure)
rt=()
[ -n "${RT_PRIORITY:-}" ] && rt=(--rt-priority "$RT_PRIORITY")
on_server=() on_client=()
if [ "${PIN:-0}" = 1 ]; then
  cpus=$(nproc)
  [ "$cpus" -ge 2 ] || { echo "bench_recovery: PIN=1 needs 2 CPUs or more" >&2; exit 2; }
  on_server=(taskset -c "$((cpus - 1))")
  on_client=(taskset -c "0-$((cpus - 2))")
fi

start_server() {  # partition db -> sets $server
  "${on_server[@]}" "$bin/server/telehand-server" "${net[@]}" --partition "$1" --db "$2" --log-level warn \
    >>"$work/server.log" 2>&1 &
  server=$!
}

session() {  # mode -> "overruns worst_us sent missing rc"
  local mode=$1 part="br-$$-$1-$RANDOM" db="$work/r-$1-$RANDOM.db"
  start_server "$part" "$db"
  sleep 1
  "${on_client[@]}" "$bin/client/telehand-client" "${net[@]}" --partition "$part" --seconds "$seconds" -q \
    "${rt[@]}" >"$work/client.log" 2>&1 &
  local client=$! rc=0
  if [ "$mode" != none ]; then
    sleep "$kill_at"
    kill "-$([ "$mode" = kill ] && echo KILL || echo TERM)" "$server"
    wait "$server" 2>/dev/null || true
    sleep "$(awk -v a="$restart_at" -v b="$kill_at" 'BEGIN{print a - b}')"
    start_server "$part" "$db"
  fi
  wait "$client" || rc=$?
  kill "$server" 2>/dev/null || true
  wait "$server" 2>/dev/null || true
  server=
  local over worst sent missing
  read -r over worst < <(sed -n 's/.*loop: \([0-9]*\) overruns, worst wake-up \([0-9]*\) us late.*/\1 \2/p' \
    "$work/client.log" | head -1; echo "? ?")
  sent=$(sed -n 's/.* \([0-9]*\) samples sent (.*/\1/p' "$work/client.log" | head -1)
  missing=$(sed -n 's/.*record: [0-9]* samples recorded, \([0-9]*\) missing.*/\1/p' "$work/client.log" | head -1)
  echo "${over:-?} ${worst:-?} ${sent:-?} ${missing:-?} $rc"
}

printf '%-6s %-5s %10s %14s %8s %8s %4s\n' round mode overruns "worst wake us" sent missing rc
for r in $(seq "$rounds"); do
  for mode in none kill term; do
    read -r over worst sent missing rc < <(session "$mode")
    printf '%-6s %-5s %10s %14s %8s %8s %4s\n' "$r" "$mode" "$over" "$worst" "$sent" "$missing" "$rc" |
      tee -a "$work/rows"
  done
done
python3 - "$work/rows" <<'PY'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1])]
print("median     overruns  worst wake us   missing")
for mode in ("none", "kill", "term"):
    def med(i):
        v = [float(r[i]) for r in rows if r[1] == mode and r[i] != "?"]
        return statistics.median(v) if v else float("nan")
    print(f"{mode:<8}{med(2):>11.1f}{med(3):>15.1f}{med(5):>10.1f}")
PY
