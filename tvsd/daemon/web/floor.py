"""The machine's floor beside the control loop: what a bare sleep loop wakes late by, right now.

The status carries the control loop's lateness (p99 and max since start); what it should be read
against is this machine's own floor (docs/architecture.md, tvsd.control.latency): the same
absolute-deadline sleep at the same rate with no work in it. `FloorProbe` runs that loop
(`latency.floor_loop`, nopython and nogil) in a worker thread for `floor_s`, every
`floor_every_s` (0: once; the first `FIRST_AFTER_S` after start), under the daemon's present
load, and keeps the last result.

The kernel is loaded from numba's cache in `__init__` (the daemon's phase 1): loading holds the
GIL for a while, which must happen before the MCU link's heartbeats start, not in the middle.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Any

from tvsd.control import latency as L

FIRST_AFTER_S = 5.0


class FloorProbe:
    def __init__(self, period_s: float, floor_s: float, every_s: float) -> None:
        self.period_s, self.floor_s, self.every_s = period_s, floor_s, every_s
        self.result: dict[str, Any] | None = None
        self.seq = 0  # bumped with each new result
        self._task: asyncio.Task[None] | None = None
        L.warm_up()

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="web-floor")

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None

    async def _run(self) -> None:
        await asyncio.sleep(FIRST_AFTER_S)  # not while the devices come up
        while True:
            ints, hist = await asyncio.to_thread(L.run_floor, self.floor_s, self.period_s)
            j = L.jitter(ints, hist)
            self.result = {
                "p50_us": j.p50_us,
                "p99_us": j.p99_us,
                "max_us": j.max_us,
                "ticks": j.ticks,
                "missed_ticks": j.missed_ticks,
                "rate_hz": 1.0 / self.period_s,
                "seconds": self.floor_s,
                "t_unix": time.time(),
            }
            self.seq += 1
            if self.every_s <= 0:
                return
            await asyncio.sleep(self.every_s)
