"""The short soak (issue 13): the SIL daemon keeps scanning under a CPU hog per core and API load.

The long version, with the timing figures, is `tvsctl bench --only soak` (tvsd/daemon/soak.py).
"""

from __future__ import annotations

import json

import pytest

from tvsd.daemon.soak import soak

SECONDS = 20.0


@pytest.mark.slow
def test_a_short_soak_under_cpu_hogs_has_no_fault_and_no_watchdog_expiry() -> None:
    """`soak(20 s)`: the SIL daemon at 25 rev/s scanning and recording, a normal-priority CPU hog
    on every core, 50 clients polling `status` back to back, a 500-call batch every 3 s, the
    recording restarted and exported every 5 s.

    Tolerance: none. No fault of any kind (nothing is injected: each one is spurious) and no
    firmware watchdog expiry (a heartbeat later than mcu.watchdog_ms: the firmware cut PWM and
    laser) may happen at all, and every recording must export. These are events, not statistics:
    a correct daemon has zero of them whatever the load, so no count above 0 is explained by the
    machine. Why 20 s is enough: the issue measured 135 watchdog cuts in 20 s of 50 polling
    clients (3 without them), and main before the link thread gave dozens in this test's 20 s
    (39 watchdog expiries, 75 faults): a daemon that passes has removed a rate of ~2 per second,
    not a rare event. What it took at the end (docs/measurements/soak-and-load.md, Soak): the host holds on
    late but complete state frames instead of latching (tvsd.control.hold), and the SIL's simulated
    firmware waits at its watchdog's edge, at most G = 500 ms, for a heartbeat the pty's kernel worker hands
    over late (tvsd.sim.mcu_wire) — both the pty's, not the daemon's: the host's own heartbeats
    stay ≤ ~15 ms apart. Passed 5 of 5 runs at merge (2 of them beside one more busy loop).
    The timing figures (missed ticks, p99 against the floor) are printed, not asserted: a test
    does not time, the benchmark does.
    """
    res = soak(SECONDS)
    print(json.dumps(res, indent=1))
    assert res["soak_watchdog_expiries"] == 0, res["soak_fault_counts"]
    assert res["soak_watchdog_expiries_firmware"] == 0, res  # the firmware's own count (its stats)
    assert res["soak_faults"] == 0, res["soak_fault_counts"]
    assert res["soak_state_end"] == "scanning"
    assert res["soak_recordings_exported"] == res["soak_recordings"], res["soak_export_errors"]
    assert res["soak_batches"] > 0 and res["soak_status_calls_per_s"] > 0  # the load did run


@pytest.mark.slow
def test_a_short_soak_under_cpu_hogs_alone_keeps_the_mcu_link() -> None:
    """`soak(20 s, no clients, no batches)`: the SIL daemon (`--realtime`, as `make run` and the
    systemd unit start it) at 25 rev/s scanning and recording beside a normal-priority CPU hog on
    every core: the busy machine of issue 13's first report, where `make run` latched "MCU state
    frames stopped" within 1–3 s. Tolerance: none, as above — a watchdog expiry or an MCU fault
    with nothing injected is a bug whatever the load; scanning goes on; every recording exports.

    IMU faults (a sensor with no sample for its `lost_margin`) fail it too: the IMU's twins'
    bus cost 6.6 ms a round trip and the FIFO overflowed every few polls (3 imu faults in 20 s
    beside a third hog); since the bus fix (one sleep per transfer, the SIL process's switch
    interval, fixed-rate polls, the reader above the event loop) 0 in 11 of 11 runs (3 of them
    failed on MCU watchdog expiries instead, at load average 25-30 from other jobs). Samples lost
    are printed, not asserted: their target (≤ 0.1 %) is the benchmark's, and a short run on a
    machine others load measures the machine.

    The MCU faults it caught in CI (`mcu_stale` with the host on time) were the SIL's pty: its
    reads and polls wait for the kernel's tty flip-buffer worker, which the hogs delay, and the
    virtual MCU's frames went out only after such a read (docs/measurements/soak-and-load.md, Soak: "the pty's
    kernel worker"; tvsd.sim.virtual_mcu.VirtualMcu.write_out and
    tvsd.sim.mcu_wire.WireModel.sent_times). The same worker delays
    a real UART's input, so the host now holds PWM 0 through late but complete frames and
    latches only on a gap in the MCU's own sequence (tvsd.control.hold, "Late input is held").
    """
    res = soak(SECONDS, clients=0, batches=False)
    print(json.dumps(res, indent=1))
    assert res["soak_watchdog_expiries"] == 0, res["soak_fault_counts"]
    assert res["soak_watchdog_expiries_firmware"] == 0, res  # the firmware's own count (its stats)
    assert res["soak_faults"] == 0, res["soak_fault_counts"]
    assert res["soak_state_end"] == "scanning"
    assert res["soak_recordings_exported"] == res["soak_recordings"], res["soak_export_errors"]
