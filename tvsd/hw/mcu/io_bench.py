"""`tvsctl bench --only mcu_io`: how late the link's I/O thread wakes while the event loop's
thread keeps the GIL busy, at the interpreter's default switch interval (5 ms) and at the 1 ms
the daemon sets (tvsd.daemon.main).

A McuLink on a pty (heartbeats every 12.5 ms: the shipped 50 ms watchdog / 4) sends on its I/O
thread while this thread runs, for `seconds` each: a pure-Python busy loop (the GIL is handed
over at the switch interval), and json.dumps of a 1 MiB reply (the API's reply cap,
daemon.rpc_max_reply_bytes: one C call that keeps the GIL throughout), and a catastrophic-
backtracking ``re`` match sized to hold the GIL >= 200 ms in C (`GilHold`). The figure is the I/O
thread's worst lateness after a heartbeat's due time (LinkStats.heartbeat_late_max_s): the
firmware cuts once a heartbeat is watchdog_ms late in all. The same loads against the heartbeat
the control kernel writes itself (the daemon's way): tvsd.control.link_bench.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import sys
import threading
import time
import tty
from typing import Any

from tvsd.hw.mcu.io_thread import IO_THREAD_PRIORITY
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings

REPLY_BYTES = 1 << 20  # daemon.rpc_max_reply_bytes' default
GIL_HOLD_S = 0.2  # 4 x the shipped 50 ms watchdog
LOADS = ("idle", "busy", "json", "regex")
CALL_KEYS = {"json": "mcu_io_json_dumps_ms", "regex": "mcu_io_regex_match_ms"}  # its longest C call


class GilHold:
    """Holds the GIL inside C for at least `at_least_s` per call: ``re.match(r'(a+)+b', 'a' * n)``
    (sre keeps the GIL for the whole match; each extra 'a' doubles its time), n sized on this
    machine when made. ``took_s``: the sizing match's duration."""

    PATTERN = re.compile(r"(a+)+b")

    def __init__(self, at_least_s: float = GIL_HOLD_S) -> None:
        n, took = 12, 0.0
        while took < at_least_s:
            n += 1 if took > at_least_s / 8 else 2
            t0 = time.perf_counter()
            self.PATTERN.match("a" * n)
            took = time.perf_counter() - t0
        self.text, self.took_s = "a" * n, took

    def __call__(self) -> float:
        t0 = time.perf_counter()
        self.PATTERN.match(self.text)
        return time.perf_counter() - t0


def run_load(load: str, seconds: float, reply: list[dict[str, Any]], hold: GilHold | None) -> float:
    """This thread runs `load` for `seconds`; returns its longest single C call (json, regex), s."""
    t_end = time.monotonic() + seconds
    longest = 0.0
    while (t := time.monotonic()) < t_end:
        if load == "busy":
            pass
        elif load == "json":
            json.dumps(reply)
            longest = max(longest, time.monotonic() - t)
        elif load == "regex" and hold is not None:
            longest = max(longest, hold())
        else:
            time.sleep(0.01)
    return longest


def _big_reply() -> list[dict[str, Any]]:
    """A batch reply of about REPLY_BYTES of JSON: 50 status-like objects."""
    row = {"t_unix": 1.7e9, "rps": 25.0, "flags": 0, "cause": "x" * 40, "values": list(range(40))}
    one = len(json.dumps(row)) + 2
    per = max(1, REPLY_BYTES // 50 // one)
    return [{"jsonrpc": "2.0", "id": k, "result": {"rows": [row] * per}} for k in range(50)]


def _drain(master: int, stop: threading.Event) -> None:
    while not stop.is_set():
        try:
            os.read(master, 65536)
        except BlockingIOError:
            time.sleep(0.005)
        except OSError:
            return


async def _measure(seconds: float) -> dict[str, Any]:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    stop = threading.Event()
    drainer = threading.Thread(target=_drain, args=(master, stop), daemon=True)
    drainer.start()
    # run under `chrt -f 40` (as tvsd --realtime runs its event loop): the I/O thread then asks
    # for the daemon's SCHED_FIFO 60 too
    fifo = os.sched_getscheduler(0) == os.SCHED_FIFO
    settings = McuSettings(port=os.ttyname(slave), watchdog_ms=50, link_lost_ms=10_000)
    link = McuLink(settings, io_priority=IO_THREAD_PRIORITY if fifo else None)
    reply = _big_reply()
    hold = GilHold()
    out: dict[str, Any] = {"mcu_io_reply_bytes": len(json.dumps(reply)), "mcu_io_fifo": fifo}
    default = sys.getswitchinterval()
    try:
        await link.open()
        link.start_heartbeat()
        for interval in (0.005, 0.001):
            sys.setswitchinterval(interval)
            tag = f"{interval * 1e3:g}ms"
            for load in LOADS:
                await asyncio.sleep(0.1)
                link.reset_peaks()
                longest = run_load(load, seconds, reply, hold)
                st = link.stats()
                out["mcu_io_thread_fifo"] = link.io_realtime
                out[f"mcu_io_late_max_ms_{load}_switch_{tag}"] = round(st.heartbeat_late_max_s * 1e3, 2)
                if load in CALL_KEYS:
                    out[CALL_KEYS[load]] = round(longest * 1e3, 1)
    finally:
        sys.setswitchinterval(default)
        await link.close()
        stop.set()
        drainer.join()
        os.close(slave)
        os.close(master)
    return out


def bench_io_thread(seconds: float = 2.0) -> dict[str, Any]:
    return asyncio.run(_measure(seconds))
