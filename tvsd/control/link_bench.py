"""`tvsctl bench --only mcu_io`, its second half: the heartbeat the control kernel writes itself
(tvsd.control.link_tx, as the daemon runs it) under the loads of tvsd.hw.mcu.io_bench, at the
daemon's 1 ms switch interval: idle, a pure-Python busy loop, json.dumps of a 1 MiB reply, and a
regex match holding the GIL >= 200 ms in C. Beside each, the I/O thread's figure of the first
half is the "before": that thread needs the GIL to send.

A real control kernel (not SIL: nothing to simulate, the kernel idles but ticks at 10 kHz) and a
McuLink on a raw pty; the far end is read and thrown away. Figures: the kernel's worst lateness
after a heartbeat's due time and its longest gap between two heartbeats written whole
(Runner.heartbeat_stats); the firmware cuts after watchdog_ms (50) without one.
"""

from __future__ import annotations

import asyncio
import os
import sys
import threading
import time
import tty
from typing import Any

from tvsd.config import load_config
from tvsd.control.runner import Runner
from tvsd.control.setup import Setup
from tvsd.hw.mcu import io_bench as IB
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings

SWITCH_INTERVAL_S = 0.001  # the daemon's (tvsd.daemon.main; control may not import the daemon)


async def _measure(seconds: float) -> dict[str, Any]:
    fifo = os.sched_getscheduler(0) == os.SCHED_FIFO  # under chrt, as tvsd --realtime
    runner = Runner(Setup.from_config(load_config(params="default")), sil=False, realtime=fifo)
    runner.start()
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    stop = threading.Event()
    drainer = threading.Thread(target=IB._drain, args=(master, stop), daemon=True)
    drainer.start()
    settings = McuSettings(port=os.ttyname(slave), watchdog_ms=50, link_lost_ms=10_000)
    link = McuLink(settings, shared_tx=runner.tx)
    reply, hold = IB._big_reply(), IB.GilHold()
    out: dict[str, Any] = {}
    default = sys.getswitchinterval()
    try:
        t_end = time.monotonic() + 120.0
        while not runner.is_running and time.monotonic() < t_end:  # loading the kernel
            await asyncio.sleep(0.05)
        await link.open()
        runner.attach_link(settings.heartbeat_period_s, link.spec.sync, link.message_id("heartbeat"),
                           link.message_id("pwm_set"))  # fmt: skip
        link.kernel_heartbeats(True)
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        for load in IB.LOADS:
            await asyncio.sleep(0.1)
            runner.reset_heartbeat_peaks()
            IB.run_load(load, seconds, reply, hold)
            hb = runner.heartbeat_stats()
            out[f"mcu_io_kernel_late_max_ms_{load}"] = round(hb.late_max_s * 1e3, 2)
            out[f"mcu_io_kernel_gap_max_ms_{load}"] = round(hb.gap_max_s * 1e3, 2)
        out["mcu_io_kernel_heartbeats"] = runner.heartbeat_stats().sent
        out["mcu_io_kernel_tx_errors"] = runner.heartbeat_stats().errors
        rt = runner.realtime_report
        out["mcu_io_kernel_fifo"] = rt.sched_fifo if rt is not None else "not requested"
    finally:
        sys.setswitchinterval(default)
        runner.detach_link()
        await link.close()
        runner.stop(timeout=2.0)
        stop.set()
        drainer.join()
        os.close(slave)
        os.close(master)
    return out


def bench_kernel_heartbeat(seconds: float = 2.0) -> dict[str, Any]:
    return asyncio.run(_measure(seconds))
