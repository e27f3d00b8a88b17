#!/usr/bin/env bash
# The soak of issue 13: the SIL daemon (--demo --realtime: spins to 25 rev/s and scans) recording,
# with both cores loaded by normal-priority CPU hogs and 50 API clients polling `status` plus a
# 500-call batch every 3 s. Prints the faults raised by kind, the loop's missed ticks and p99
# lateness, what the API answered, and whether the recording exports.
#   usage: scripts/soak.sh [SECONDS (600)] [CLIENTS (50)]      run from the checkout, after make
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-600}; clients=${2:-50}
bin=.venv/bin
dir=$(mktemp -d /tmp/tvsd-soak.XXXXXX)
export TVSD_SOCKET=$dir/tvsd.sock
"$bin/tvsd" --sil --demo --realtime --socket "$TVSD_SOCKET" --data-dir "$dir/data" > "$dir/tvsd.log" 2>&1 &
daemon=$!
trap 'kill $daemon 2>/dev/null || true; wait $daemon 2>/dev/null || true' EXIT
state() { "$bin/tvsctl" status --json --timeout 5 2>/dev/null | "$bin/python" -c 'import json,sys; print(json.load(sys.stdin)["state"])' 2>/dev/null || true; }
for _ in $(seq 120); do [ "$(state)" = scanning ] && break; sleep 1; done
echo "before the load: $(state)"
"$bin/tvsctl" record start > /dev/null
hogs=()
for _ in $(seq "$(nproc)"); do timeout "$seconds" sh -c 'while :; do :; done' & hogs+=($!); done
api=$("$bin/python" scripts/soak_clients.py "$TVSD_SOCKET" "$seconds" "$clients")
wait "${hogs[@]}" 2>/dev/null || true
"$bin/tvsctl" record stop > /dev/null || true
"$bin/tvsctl" status --json | "$bin/python" -c '
import json, sys
s = json.load(sys.stdin)
loop, faults = s["loop"], s["fault_counts"] or "none"
print("after", sys.argv[1], "s: state", s["state"] + "; faults by kind", faults)
print("control loop: missed ticks %d, p99 lateness %.1f us, max %.0f us"
      % (loop["missed_ticks"], loop["jitter_p99_us"], loop["jitter_max_us"]))
' "$seconds"
echo "API: $api"
exported=0; total=0
for rec in "$dir"/data/rec-*; do
    total=$((total + 1))
    "$bin/tvsctl" export "$rec" --csv "$rec.csv" > /dev/null 2>&1 && exported=$((exported + 1))
done
echo "recordings exported: $exported of $total"
