#!/usr/bin/env bash
# The server's memory under floods of sessions (docs/security.md "Bounds"): one
# telehand-server (with the Bullet hand), a first session and its end (the baseline: what
# the server keeps once it has served one), then ROUNDS rounds of
#   - a burst: 10,000 OPENs from 16 participants at once (the server opens
#     server.max_sessions = 64 and refuses the rest), RSS sampled every 50 ms (the peak);
#   - a churn: SESSIONS sessions opened and closed (16 participants, each keeping 4
#     sessions opening or open, every OPEN taken);
# and the server's RSS once each has ended and been retired (status_keep_s = 2 s) and the
# server has made its DDS participant again (server.renew_when_idle, half a second later):
# SETTLE seconds (5) after the last one ended, and not before that renewal (waited for up to
# 60 s more). RENEW=false: without the renewal.
# With BENCH_SMAPS=1, the server's largest resident mappings at the end (/proc/PID/smaps:
# [heap] is the main malloc arena, anonymous 64 MB-aligned ones the threads' arenas); with
# BENCH_WALK=1, what holds the main arena (tests/bench/heap_walk.py).
# Usage: tests/bench/bench_server_memory.sh [ROUNDS (3)] [SESSIONS per churn (9000)] [--secure]
set -euo pipefail
cd "$(dirname "$0")/../.."
rounds=${1:-3}
sessions=${2:-9000}
mode=${3:-}
bin=build/release
work=$(mktemp -d /tmp/telehand-bench-memory-XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$work"' EXIT
net=(--dds-config deploy/cyclonedds/loopback.xml --partition "bm-$$-$RANDOM")
if [ "$mode" = --secure ]; then
  deploy/pki/make-pki.sh "$work/pki" >/dev/null
  net+=(--pki "$work/pki")
else
  net+=(--insecure)
fi
printf '[server]\nstatus_keep_s = 2.0\nrenew_when_idle = %s\n' "${RENEW:-true}" >"$work/server.toml"
"$bin/server/telehand-server" --config "$work/server.toml" --db "$work/records.db" \
  --log-level info "${net[@]}" >"$work/server.log" 2>&1 &
server=$!
inject() { "$bin/tests/integration/telehand-test-inject" "$@" "${net[@]}" 2>/dev/null; }
rss() { awk '/^VmRSS/{print $2}' "/proc/$server/status"; }
# The anonymous part (the heap, the threads' arenas and stacks): the rest of the RSS is the
# program's and libraries' pages, read from their files as code paths are first taken.
anon() { awk '/^RssAnon/{print $2}' "/proc/$server/status"; }
pct() { awk -v a="$1" -v b="$2" 'BEGIN{printf "%+.1f%%", 100 * (a - b) / b}'; }
mb() { awk -v k="$1" 'BEGIN{printf "%.1f", k / 1024}'; }
settle=${SETTLE:-5}
renewals() { grep -c 'DDS participant made again' "$work/server.log" || true; }
# Once a phase's injector has ended: SETTLE seconds, and (with the renewal) until the server
# has made its participant again since, at most 60 s more: on a busy machine the sessions
# end and are retired later, and an RSS read before the renewal is the one without it.
settled() {
  local before
  before=$(renewals)
  sleep "$settle"
  [ "${RENEW:-true}" = true ] || return 0
  local waited=0
  while [ "$(renewals)" -le "$before" ] && [ "$waited" -lt 600 ]; do
    sleep 0.1
    waited=$((waited + 1))
  done
  [ "$waited" -lt 600 ] || echo "the server did not make its participant again within 60 s"
  [ "$waited" -eq 0 ] || sleep 1
}
inject open-flood --count 1 --hold 0 >/dev/null
settled
base=$(rss)
base_anon=$(anon)
printf 'baseline (one session served): %s MB (anonymous %s MB)\n' "$(mb "$base")" "$(mb "$base_anon")"
printf '%-6s %-22s %10s %10s %9s %10s %9s\n' round what "peak MB" "after MB" "vs base" "anon MB" "vs base"
for r in $(seq "$rounds"); do
  inject open-flood --count 10000 --participants 16 --hold 3 >"$work/flood.log" &
  flood=$!
  peak=0
  while kill -0 "$flood" 2>/dev/null; do
    now=$(rss)
    [ "$now" -gt "$peak" ] && peak=$now
    sleep 0.05
  done
  wait "$flood" || echo "flood: $(cat "$work/flood.log")"
  settled
  after=$(rss)
  after_anon=$(anon)
  printf '%-6s %-22s %10s %10s %9s %10s %9s\n' "$r" "burst 10000 OPENs" "$(mb "$peak")" \
    "$(mb "$after")" "$(pct "$after" "$base")" "$(mb "$after_anon")" "$(pct "$after_anon" "$base_anon")"
  peak=0
  inject open-churn --count "$sessions" --participants 16 >"$work/churn.log" &
  churn=$!
  while kill -0 "$churn" 2>/dev/null; do
    now=$(rss)
    [ "$now" -gt "$peak" ] && peak=$now
    sleep 0.2
  done
  wait "$churn" || true
  settled
  after=$(rss)
  after_anon=$(anon)
  printf '%-6s %-22s %10s %10s %9s %10s %9s   (%s)\n' "$r" "churn $sessions sessions" \
    "$(mb "$peak")" "$(mb "$after")" "$(pct "$after" "$base")" "$(mb "$after_anon")" \
    "$(pct "$after_anon" "$base_anon")" "$(tr '\n' ' ' <"$work/churn.log")"
done
printf 'the server made its DDS participant again %s times\n' \
  "$(renewals)"
if [ "${BENCH_SMAPS:-}" = 1 ]; then
  echo "largest resident mappings (kB):"
  awk '/^[0-9a-f]+-[0-9a-f]+ /{m=$1" "$6} /^Rss:/{if ($2 > 0) print $2, m}' "/proc/$server/smaps" |
    sort -rn | head -12
fi
if [ "${BENCH_WALK:-}" = 1 ]; then
  tests/bench/heap_walk.py "$server" --top 12
fi
