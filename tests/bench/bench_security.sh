#!/usr/bin/env bash
# What DDS Security costs (docs/security.md "Cost"): the same runs without it, with it
# (telehand's cryptography plugin) and with it on Cyclone's own cryptography plugin
# (TELEHAND_DDS_CRYPTO=cyclone), interleaved (insecure, secure, cyclone, insecure, ...) so
# that all see the same machine load, and the medians over the rounds of each figure, with
# each secured mode's difference from the unsecured one.
#   - DeviceState latency: telehand-latency (DeviceState-sized pings at 1 kHz through a
#     self echo), one-way p50/p99;
#   - the haptic loop: a telehand-server + telehand-client session on loopback, the
#     client's overruns and worst wake-up.
# Usage: tests/bench/bench_security.sh [ROUNDS (default 5)] [SECONDS per run (default 8)]
set -euo pipefail
cd "$(dirname "$0")/../.."
rounds=${1:-5}
seconds=${2:-8}
bin=build/release
work=$(mktemp -d /tmp/telehand-bench-security-XXXXXX)
trap 'kill $(jobs -p) 2>/dev/null || true; wait 2>/dev/null || true; rm -rf "$work"' EXIT
deploy/pki/make-pki.sh "$work/pki" >/dev/null
net=(--dds-config deploy/cyclonedds/loopback.xml)

security() {  # mode -> the flags and the cryptography plugin's choice
  case $1 in
    insecure) sec=(--insecure) crypto=telehand ;;
    secure) sec=(--pki "$work/pki") crypto=telehand ;;
    cyclone) sec=(--pki "$work/pki") crypto=cyclone ;;
  esac
}

latency() {  # mode -> "p50 p99" in us
  local sec=() crypto tag=$1
  security "$tag"
  TELEHAND_DDS_CRYPTO=$crypto "$bin/client/telehand-latency" "${net[@]}" "${sec[@]}" --partition "bs-$$-$tag-$RANDOM" \
    --echo self --seconds "$seconds" --rate 1000 --quiet --json "$work/lat.json" >/dev/null 2>&1
  python3 -c "
import json; p = json.load(open('$work/lat.json'))['telehand']['pooled']
print(round(p['p50_us'], 1), round(p['p99_us'], 1))" 2>/dev/null || echo "? ?"
}

session() {  # mode -> "overruns worst_us"
  local sec=() crypto tag=$1 part="bs-$$-$1-$RANDOM"
  security "$tag"
  TELEHAND_DDS_CRYPTO=$crypto "$bin/server/telehand-server" "${net[@]}" "${sec[@]}" --partition "$part" \
    --db "$work/r-$tag.db" --log-level warn >/dev/null 2>&1 &
  local server=$!
  TELEHAND_DDS_CRYPTO=$crypto "$bin/client/telehand-client" "${net[@]}" "${sec[@]}" --partition "$part" \
    --seconds "$seconds" -q >"$work/client.log" 2>&1 || true
  kill "$server" 2>/dev/null || true
  wait "$server" 2>/dev/null || true
  sed -n 's/.*loop: \([0-9]*\) overruns, worst wake-up \([0-9]*\) us late.*/\1 \2/p' "$work/client.log"
}

printf '%-6s %-9s %12s %12s %10s %14s\n' round mode "p50 us" "p99 us" overruns "worst wake us"
for r in $(seq "$rounds"); do
  for mode in insecure secure cyclone; do
    read -r p50 p99 < <(latency "$mode")
    read -r over worst < <(session "$mode")
    printf '%-6s %-9s %12s %12s %10s %14s\n' "$r" "$mode" "$p50" "$p99" "$over" "$worst" |
      tee -a "$work/rows"
  done
done
# Medians per mode, and each secured mode against the unsecured one.
python3 - "$work/rows" <<'PY'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1])]
cols = ["p50 us", "p99 us", "overruns", "worst wake us"]
med = {}
for mode in ("insecure", "secure", "cyclone"):
    vals = [[float(r[2 + i]) for r in rows if r[1] == mode and r[2 + i] != "?"] for i in range(4)]
    med[mode] = [statistics.median(v) if v else float("nan") for v in vals]
print("median    " + "".join(f"{c:>15}" for c in cols))
for mode in ("insecure", "secure", "cyclone"):
    print(f"{mode:<10}" + "".join(f"{x:>15.1f}" for x in med[mode]))
for mode in ("secure", "cyclone"):
    print(f"{mode + ' %':<10}" + "".join(
        f"{100 * (s - i) / i:>+14.1f}%" if i else f"{'-':>15}"
        for s, i in zip(med[mode], med["insecure"])))
PY
