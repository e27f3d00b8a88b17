#!/usr/bin/env bash
# The soak of issue 13, kept as a short name for `tvsctl bench --only soak` (tvsd/daemon/soak.py):
# the SIL daemon at 25 rev/s scanning and recording, a normal-priority CPU hog on every core, CLIENTS
# API clients polling `status` and a 500-call batch every 3 s; faults by kind, watchdog expiries,
# missed ticks and p99 lateness beside the floor, IMU samples lost, recordings exported; exit 1 when
# a target is missed.
#   usage: scripts/soak.sh [SECONDS (600)] [CLIENTS (50)] [--json]     run from the checkout, after make
set -euo pipefail
cd "$(dirname "$0")/.."
exec .venv/bin/tvsctl bench --only soak --seconds "${1:-600}" --clients "${2:-50}" "${@:3}"
