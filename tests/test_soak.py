"""The short soak (issue 13): the SIL daemon keeps scanning under a CPU hog per core and API load.

The long version, with the timing figures, is `tvsctl bench --only soak` (tvsd/daemon/soak.py).
"""

from __future__ import annotations

import json

import pytest

from tvsd.daemon.soak import soak

SECONDS = 20.0


@pytest.mark.slow
@pytest.mark.xfail(
    strict=False,
    reason="issue 13: the MCU link's heartbeats still share the event loop with the API and the SIL "
    "devices share the daemon's process (branches iothread, silproc); on main a 20 s soak raised "
    "39 firmware watchdog expiries and 75 faults. The lead re-checks after merging them.",
)
def test_a_short_soak_under_cpu_hogs_has_no_fault_and_no_watchdog_expiry() -> None:
    """`soak(20 s)`: the SIL daemon at 25 rev/s scanning and recording, a normal-priority CPU hog
    on every core, 50 clients polling `status` back to back, a 500-call batch every 3 s, the
    recording restarted and exported every 5 s.

    Tolerance: none. No fault of any kind (nothing is injected: each one is spurious) and no
    firmware watchdog expiry (a heartbeat later than mcu.watchdog_ms: the firmware cut PWM and
    laser) may happen at all, and every recording must export. These are events, not statistics:
    a correct daemon has zero of them whatever the load, so no count above 0 is explained by the
    machine. Why 20 s is enough: the issue measured 135 watchdog cuts in 20 s of 50 polling
    clients (3 without them), and today's main gives dozens in this test's 20 s (39 watchdog
    expiries, 75 faults): a daemon that passes has removed a rate of ~2 per second, not a rare
    event. The timing figures (missed ticks, p99 against the floor) are printed, not asserted: a
    test does not time, the benchmark does.
    """
    res = soak(SECONDS)
    print(json.dumps(res, indent=1))
    assert res["soak_watchdog_expiries"] == 0, res["soak_fault_counts"]
    assert res["soak_faults"] == 0, res["soak_fault_counts"]
    assert res["soak_state_end"] == "scanning"
    assert res["soak_recordings_exported"] == res["soak_recordings"], res["soak_export_errors"]
    assert res["soak_batches"] > 0 and res["soak_status_calls_per_s"] > 0  # the load did run
