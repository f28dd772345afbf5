#!/usr/bin/env bash
# The demo: installs what is missing, builds, then runs a full session on loopback DDS:
# telehand-server, telehand-client with the simulated MF-2 performing a 20 s MCP
# mobilization at 3 Hz, and telehand-watch following it as a supervisor would, all under
# DDS Security with a throw-away PKI (each program as its role: server, device, supervisor).
# Options: --seconds N (default 20), --frequency HZ (default 3), --insecure (no DDS Security),
# --lesson (a whole lesson instead: a clinician's demonstration, the lesson made from it, a
# simulated student's run with a watcher, and its report; about 2 minutes),
# --massage-seconds N (default 10; 0 skips it): after the mobilization, the circular massage
# of the thumb-index web on the same server.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
seconds=20
frequency=3
security=on
lesson=off
massage_seconds=10
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds=$2; shift 2 ;;
    --frequency) frequency=$2; shift 2 ;;
    --insecure) security=off; shift ;;
    --lesson) lesson=on; shift ;;
    --massage-seconds) massage_seconds=$2; shift 2 ;;
    -h|--help) sed -n '2,10p' "$0"; exit 0 ;;
    *) echo "demo: unknown option '$1' (try --help)" >&2; exit 2 ;;
  esac
done

./deploy/setup.sh
./deploy/build.sh release
bin=$root/build/release
dds=(--dds-config "$root/deploy/cyclonedds/loopback.xml" --partition "demo-$$")
db=$root/records/telehand.db
logs=$root/records/demo-logs
mkdir -p "$logs"

pids=()
pki=""
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do wait "$p" 2>/dev/null || true; done
  [ -z "$pki" ] || rm -rf "$pki"
}
trap cleanup EXIT INT TERM

if [ "$security" = on ]; then
  pki=$(mktemp -d /tmp/telehand-demo-pki-XXXXXX)
  ./deploy/pki/make-pki.sh "$pki/pki" >/dev/null
  dds+=(--pki "$pki/pki")
  secured="DDS Security (throw-away PKI)"
else
  dds+=(--insecure)
  secured="no DDS Security"
fi

if [ "$lesson" = on ]; then
  echo "== telehand lesson demo: server; a clinician's demonstration; the lesson; a student's run with a watcher; the report; loopback DDS, $secured"
  "$bin/server/telehand-server" --db "$db" "${dds[@]}" >"$logs/server.log" 2>&1 &
  pids+=($!)
  echo "-- 1. the clinician demonstrates a 3 Hz mobilization (10 s)"
  "$bin/client/telehand-client" "${dds[@]}" --seconds 10 --frequency "$frequency" \
    --user demo-clinician -q >"$logs/clinician.log" 2>&1 || {
    echo "demo: the clinician's session failed; logs in $logs" >&2
    exit 1
  }
  demo=$(sed -n 's/^session \([0-9]*\) open.*/\1/p' "$logs/clinician.log" | head -n 1)
  grep -E '^  record:' "$logs/clinician.log" || true
  echo "-- 2. a lesson from it"
  "$bin/server/telehand-records" --db "$db" lesson create --demo "$demo" --guided 2 \
    --attempts 3 --trial-seconds 8 --schedule terminal | tee "$logs/lesson.log"
  lesson_id=$(sed -n 's/^lesson \([0-9]*\) .*/\1/p' "$logs/lesson.log" | head -n 1)
  echo "-- 3. a student runs it: baseline, watch, 2 guided trials, 3 attempts, reassessment"
  "$bin/client/telehand-client" "${dds[@]}" --lesson "$lesson_id" --user demo-student \
    --force-bias 1.5 --frequency-error 0.3 --tremor 0.5 --explore-seconds 30 \
    >"$logs/student.log" 2>&1 &
  client=$!
  pids+=($client)
  sleep 1
  "$bin/client/telehand-watch" "${dds[@]}" --exit-on-close --wait 15 --plain \
    >"$logs/watch.log" 2>&1 || true
  status=0
  wait "$client" || status=$?
  grep -E '^phase|feedback:|^summary|record:|lesson:' "$logs/student.log" || true
  run=$(sed -n 's/^session \([0-9]*\) open.*/\1/p' "$logs/student.log" | head -n 1)
  if [ "$status" -ne 0 ] || [ -z "$run" ]; then
    echo "demo: the student's run failed (exit $status); logs in $logs" >&2
    exit 1
  fi
  echo "-- 4. the report"
  "$bin/server/telehand-records" --db "$db" report "$run" -o "$root/records/reports"
  echo
  echo "Lesson $lesson_id (demonstration: session $demo); the student's run: session $run in $db"
  echo "Show it:  $bin/server/telehand-records --db $db lesson show $lesson_id"
  echo "Replay the demonstration (with a server running on this record):  telehand-watch --replay $demo"
  exit 0
fi

echo "== telehand demo: server, simulated-MF-2 client (${seconds} s, ${frequency} Hz), watcher; loopback DDS, $secured"
"$bin/server/telehand-server" --db "$db" "${dds[@]}" >"$logs/server.log" 2>&1 &
pids+=($!)

"$bin/client/telehand-client" "${dds[@]}" --seconds "$seconds" --frequency "$frequency" \
  --user demo-student >"$logs/client.log" 2>&1 &
client=$!
pids+=($client)

sleep 1  # the supervisor joins late, as supervisors do
if [ -t 1 ]; then
  "$bin/client/telehand-watch" "${dds[@]}" --exit-on-close --wait 15 || true
else
  "$bin/client/telehand-watch" "${dds[@]}" --exit-on-close --wait 15 --plain \
    >"$logs/watch.log" 2>&1 || true
  echo "-- watcher (last lines of $logs/watch.log)"
  tail -n 3 "$logs/watch.log"
fi

status=0
wait "$client" || status=$?
echo "-- client"
cat "$logs/client.log" | grep -v '^\s*$' | tail -n 6
session=$(sed -n 's/^session \([0-9]*\) open.*/\1/p' "$logs/client.log" | head -n 1)
if [ "$status" -ne 0 ] || [ -z "$session" ]; then
  echo "demo: the client failed (exit $status); logs in $logs" >&2
  exit 1
fi
massage=""
if [ "$massage_seconds" != 0 ]; then
  echo "-- massage: the simulated clinician circles on the thumb-index web (${massage_seconds} s, 10 ± 2 N)"
  if ! "$bin/client/telehand-client" "${dds[@]}" --technique massage --seconds "$massage_seconds" \
    --user demo-student >"$logs/massage.log" 2>&1; then
    echo "demo: the massage client failed; logs in $logs" >&2
    cat "$logs/massage.log" >&2
    exit 1
  fi
  grep -E '^session|massage:|record:' "$logs/massage.log" || true
  massage=$(sed -n 's/^session \([0-9]*\) open.*/\1/p' "$logs/massage.log" | head -n 1)
fi
echo
echo "Record: session $session in $db (server log: $logs/server.log)"
echo "List sessions:  $bin/server/telehand-records --db $db list"
echo "Export to CSV:  $bin/server/telehand-records --db $db export $session -o session-$session.csv"
if [ -n "$massage" ]; then
  echo "The massage: session $massage (each pad's depth and the web's force in its CSV columns *_depth_m, *_tissue?_n)"
fi
