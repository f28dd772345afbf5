#!/usr/bin/env bash
# A session across an emulated WAN with real processes: two network namespaces joined by
# telehand-linkem (user-space delay line), the server in one, the device client in the other,
# both on deploy/cyclonedds/wan.xml. Needs root (network namespaces, TUN).
#
#   deploy/linkem.sh PROFILE [SECONDS] [extra telehand-client options...]
#   deploy/linkem.sh deploy/links/extreme.toml 60 --deadband 0.05
#
# Prints the client's summary and the delay line's statistics; cleans up its namespaces and
# the processes it started (by PID) however it ends.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
b="${TELEHAND_BUILD:-$root/build/release}"
profile="${1:?usage: deploy/linkem.sh PROFILE [SECONDS] [client options...]}"
seconds="${2:-20}"
shift $(( $# >= 2 ? 2 : 1 ))
[ -f "$profile" ] || { echo "linkem.sh: no link profile '$profile'" >&2; exit 2; }
[ "$(id -u)" -eq 0 ] || { echo "linkem.sh: needs root (network namespaces)" >&2; exit 2; }

tag="thl$$"
work="$(mktemp -d /tmp/telehand-linkem-XXXXXX)"
pids=()
cleanup() {
  # Newest first: the server before the delay line whose interface it needs to shut down.
  for ((i = ${#pids[@]} - 1; i >= 0; i--)); do
    kill "${pids[$i]}" 2>/dev/null || true
    wait "${pids[$i]}" 2>/dev/null || true
  done
  ip netns del "${tag}a" 2>/dev/null || true
  ip netns del "${tag}b" 2>/dev/null || true
}
trap cleanup EXIT INT TERM

# Across the delay line as across a WAN: under DDS Security, with a throw-away PKI.
"$root/deploy/pki/make-pki.sh" "$work/pki" >/dev/null

ip netns add "${tag}a"
ip netns add "${tag}b"
"$b/tools/telehand-linkem" --ns-a "${tag}a" --ns-b "${tag}b" --profile "$profile" >"$work/linkem.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do grep -q "linkem ready" "$work/linkem.log" && break; sleep 0.05; done
grep "linkem ready" "$work/linkem.log" || { cat "$work/linkem.log" >&2; exit 1; }

export TELEHAND_DDS_ADDRESS=10.77.0.1 TELEHAND_DDS_PEER=10.77.0.2
ip netns exec "${tag}a" "$b/server/telehand-server" --dds-config "$root/deploy/cyclonedds/wan.xml" \
  --pki "$work/pki" --partition "$tag" --db "$work/records.db" --log-level warn >"$work/server.log" 2>&1 &
pids+=($!)
export TELEHAND_DDS_ADDRESS=10.77.0.2 TELEHAND_DDS_PEER=10.77.0.1
rc=0
ip netns exec "${tag}b" "$b/client/telehand-client" --dds-config "$root/deploy/cyclonedds/wan.xml" \
  --pki "$work/pki" --partition "$tag" --seconds "$seconds" --connect-timeout 30 -q "$@" || rc=$?
# The server first: Cyclone's shutdown needs its interface (the TUN) to wake its receive thread.
for i in 1 0; do
  kill "${pids[$i]}" 2>/dev/null || true
  wait "${pids[$i]}" 2>/dev/null || true
done
grep -E "^(a->b|b->a)" "$work/linkem.log" || true
echo "record: $work/records.db"
exit $rc
