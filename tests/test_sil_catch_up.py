"""SIL catch-up: host bytes enter the virtual MCU at their arrival's time on the pacing line.

The paced plant advances the virtual MCU's manual clock. When the plant's thread falls behind
(the SIL process starved, a GC) and then catches up, the heartbeats that came meanwhile used to
go into the core at its stale time, all at once, and the catch-up then ran the core on with no
heartbeat at all: the firmware saw a gap that never was on the wire, and its watchdog cut PWM
and laser. Now each read is stamped on arrival and fed to the core when its clock reaches that
time (tvsd.sim.virtual_mcu.VirtualMcu.rx_timeline).
"""

from __future__ import annotations

import asyncio
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from conftest import until

from tvsd.config import load_config
from tvsd.hw.mcu.events import FaultEvent
from tvsd.hw.mcu.io_thread import IO_THREAD_PRIORITY
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings
from tvsd.sim import mcu_plant as mp
from tvsd.sim import virtual_mcu as vm
from tvsd.sim.sil_process import SIL_PRIORITY

WATCHDOG_MS = 200  # heartbeats every 50 ms: a loaded test host keeps its gaps well inside
STALL_S = 0.6  # three watchdogs: before the fix the catch-up always crossed one


@contextmanager
def realtime(priority: int) -> Iterator[bool]:
    """SCHED_FIFO for this thread and the threads it starts meanwhile (the plant's, the virtual
    MCU's pump), as in the SIL devices' process under --realtime; restored after."""
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        granted = True
    except OSError:
        granted = False
    try:
        yield granted
    finally:
        os.sched_setscheduler(0, policy, param)


def test_a_stalled_plant_that_catches_up_sees_every_heartbeat_and_a_real_gap_still_cuts() -> None:
    """Stall the plant's thread STALL_S while the link keeps sending heartbeats: no watchdog
    expiry once it has caught up (before: one or two on every run, the core ran 0.6 s past its
    last heartbeat). Then stop the heartbeats: the watchdog expires (the timeline still carries
    time, and the watchdog is armed). Tolerance: none on the first, an event with nothing
    missing on the wire. The wire must have no gap itself: the link's thread and the plant's
    and pump's run SCHED_FIFO as in the daemon and the SIL process under --realtime (at normal
    priority on this loaded host the link's own heartbeats came 350 ms apart once), and the
    link's largest heartbeat gap is checked to be under the watchdog."""
    cfg = load_config()
    with realtime(SIL_PRIORITY) as rt:
        try:
            plant = mp.McuPlant(cfg, speed=1.0, record=False)
        except vm.VirtualMcuError as exc:
            pytest.skip(f"virtual MCU unavailable: {exc}")
        with plant:
            _stall_and_check(plant, IO_THREAD_PRIORITY if rt else None)


def _stall_and_check(plant: mp.McuPlant, io_priority: int | None) -> None:
    faults: list[FaultEvent] = []
    stall = threading.Event()
    stalled = threading.Event()
    step = plant.step

    def stalling_step() -> None:
        if stall.is_set() and not stalled.is_set():
            stalled.set()
            time.sleep(STALL_S)  # the plant's thread only: the pump reads on, the link sends on
        step()

    plant.step = stalling_step  # type: ignore[method-assign]

    async def main() -> None:
        settings = McuSettings(port=plant.mcu.port, watchdog_ms=WATCHDOG_MS, link_lost_ms=10_000)
        async with McuLink(settings, on_fault=faults.append, io_priority=io_priority) as link:
            assert link.send_config(watchdog_ms=WATCHDOG_MS, state_div=10, max_on_ms=0)
            assert link.send_pwm(0.3)
            await until(lambda: plant.mcu.pwm_duty > 0.29, 5.0, "duty applied")
            plant.start()
            await until(lambda: plant.t >= 0.3, 10.0, "the plant runs")
            before = len(faults)
            stall.set()
            await until(stalled.is_set, 5.0, "the stall began")
            t_stall = plant.t
            # caught up: the plant 2 watchdogs past the stall's end on its own line
            await until(lambda: plant.t >= t_stall + STALL_S + 0.4, 20.0, "the plant caught up")
            gap = link.stats().heartbeat_gap_max_s
            assert gap < WATCHDOG_MS / 1e3, f"the host's own heartbeats {1e3 * gap:.0f} ms apart"
            assert faults[before:] == [], faults[before:]
            assert plant.mcu.pwm_duty > 0.29  # the watchdog did not cut
            await link.stop_heartbeat()
            await until(lambda: len(faults) > before, 5.0, "the watchdog expires without heartbeats")
            assert faults[-1].name == "watchdog_expired" and faults[-1].detail == WATCHDOG_MS
            await until(lambda: plant.mcu.pwm_duty == 0.0, 2.0, "PWM cut")

    asyncio.run(main())
