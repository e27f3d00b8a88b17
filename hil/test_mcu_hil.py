"""MCU hardware-in-the-loop: the real board on TVSD_MCU_PORT.

  TVSD_MCU_PORT=/dev/ttyUSB0 pytest hil/test_mcu_hil.py -m hil -s

Everything skips, with the reason, when TVSD_MCU_PORT is unset or not there. Tests that move
hardware also need an explicit yes, because they spin the motor or drive the steppers:
  TVSD_HIL_PULSE_HZ=100  a square wave of this frequency on both sensor inputs (zero: PD2/INT0,
                         optical: PB0/ICP1), from a signal generator or a second board
  TVSD_HIL_MOTOR=1       the SA motor is free to spin (duty 30 % for 2 s)
  TVSD_HIL_STEPPERS=1    φ and γ are free to move, home switches wired
"""

from __future__ import annotations

import asyncio
import math
import os
import statistics
from collections.abc import Callable, Coroutine
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from tvsd.hw.mcu.events import FaultEvent, PulseEvent
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
from tvsd.hw.mcu.steppers import Steppers

PORT = os.environ.get("TVSD_MCU_PORT", "")
BAUD = int(os.environ.get("TVSD_MCU_BAUD", "2000000"))

pytestmark = [
    pytest.mark.hil,
    pytest.mark.skipif(not PORT, reason="TVSD_MCU_PORT is not set (e.g. /dev/ttyUSB0)"),
    pytest.mark.skipif(bool(PORT) and not Path(PORT).exists(), reason=f"TVSD_MCU_PORT={PORT} does not exist"),
]


def run(fn: Callable[[McuLink], Coroutine[Any, Any, None]], **kw: Any) -> None:
    async def main() -> None:
        async with McuLink(McuSettings(port=PORT, baud=BAUD), **kw) as link:
            await fn(link)

    asyncio.run(main())


def test_identify() -> None:
    async def body(link: McuLink) -> None:
        spec = load_spec()
        assert link.identity is not None
        # TVSD_HIL_BOARD=host runs these against the virtual MCU, to check the tests themselves
        assert spec.boards.get(link.identity.board) == os.environ.get("TVSD_HIL_BOARD", "atmega328p")
        assert link.identity.table_hash == spec.table_hash
        assert link.identity.clock_hz == 16_000_000

    run(body)


def test_round_trip_latency_histogram() -> None:
    async def body(link: McuLink) -> None:
        rtts = []
        for _ in range(1000):
            rtts.append(await link.ping())
            await asyncio.sleep(0.002)
        us = sorted(r * 1e6 for r in rtts)
        edges = [0, 250, 500, 1000, 2000, 5000, 10000, 20000, math.inf]
        print("\nheartbeat round trip (µs), 1000 samples:")
        for lo, hi in pairwise(edges):
            n = sum(lo <= u < hi for u in us)
            print(f"  {lo:>6}–{hi:<6} {n:5d} {'#' * (n * 60 // len(us))}")
        p50, p99 = statistics.median(us), us[989]
        print(f"  min {us[0]:.0f}  p50 {p50:.0f}  p99 {p99:.0f}  max {us[-1]:.0f}")
        # The wire alone is 24 bytes × 5 µs = 120 µs at 2 Mbaud; USB full speed adds 1 ms frames.
        # An FTDI chip with its default 16 ms latency timer lands far above 5 ms: that is the fix.
        assert p50 < 5000, (
            f"median RTT {p50:.0f} µs: set the USB-serial latency timer to 1 ms "
            "(echo 1 > /sys/bus/usb-serial/devices/ttyUSB0/latency_timer)"
        )
        st = link.stats()
        assert st.crc_errors == 0 and st.lost_frames == 0

    run(body)


@pytest.mark.skipif("TVSD_HIL_PULSE_HZ" not in os.environ, reason="TVSD_HIL_PULSE_HZ not set")
def test_pulse_inputs_with_a_known_signal() -> None:
    f = float(os.environ["TVSD_HIL_PULSE_HZ"])
    pulses: list[PulseEvent] = []

    async def body(link: McuLink) -> None:
        await asyncio.sleep(3.0)
        st = link.stats()
        assert st.lost_events == 0, f"{st.lost_events} pulse events lost"
        for ch in (0, 1):
            t = [p.mcu_ticks for p in pulses if p.channel == ch]
            assert len(t) > 2 * f, f"channel {ch}: {len(t)} edges in 3 s at {f} Hz"
            periods = [(b - a) / 16e6 for a, b in pairwise(t)]
            mean, sd = statistics.fmean(periods), statistics.stdev(periods)
            print(f"\nchannel {ch}: period {mean * 1e6:.2f} µs, jitter {sd * 1e6:.3f} µs")
            # The MCU's ceramic resonator / crystal is within ±0.5 % (the generator far better).
            assert mean == pytest.approx(1 / f, rel=5e-3)
            # ICP1 latches in hardware: jitter ~1 tick; INT0 is stamped in an ISR: a few µs.
            assert sd < (1e-6 if ch == 1 else 20e-6)

    run(body, on_pulse=pulses.append)


@pytest.mark.skipif(os.environ.get("TVSD_HIL_MOTOR") != "1", reason="TVSD_HIL_MOTOR=1 not set")
def test_motor_spin_up_and_watchdog() -> None:
    states: list[StateSample] = []
    faults: list[FaultEvent] = []

    async def body(link: McuLink) -> None:
        loop = asyncio.get_running_loop()
        t_end = loop.time() + 2.0
        while loop.time() < t_end:  # the control thread's job, at 1 kHz here
            link.send_pwm(0.3)
            await asyncio.sleep(0.001)
        counts = states[-1].encoder - states[len(states) // 2].encoder
        assert abs(counts) > 100, "encoder did not move: check motor power and encoder A/B"
        # Heartbeats stop: the firmware must cut the outputs within watchdog_ms (200 ms by
        # default) + one 0.1 ms tick; + 20 ms for the fault frame to cross USB.
        await link.stop_heartbeat()
        t0 = loop.time()
        while not any(f.name == "watchdog_expired" for f in faults):
            assert loop.time() - t0 < 0.22, "no watchdog_expired fault within 220 ms"
            await asyncio.sleep(0.001)
        # and it refuses outputs until the next heartbeat
        refused = len(link.refusals)
        link.send_pwm(0.3)
        await asyncio.sleep(0.05)
        assert len(link.refusals) == refused + 1 and link.refusals[-1].status == 2

    run(body, on_state=states.append, on_fault=faults.append)


@pytest.mark.skipif(os.environ.get("TVSD_HIL_STEPPERS") != "1", reason="TVSD_HIL_STEPPERS=1 not set")
def test_stepper_homing_and_move() -> None:
    async def body(link: McuLink) -> None:
        steppers = Steppers(link)
        link.on_stepper = steppers.update
        link.on_refused = lambda r: steppers.refused(r.name, r.values, r.reason)
        for axis, target in (("phi", 45.0), ("gamma", 0.0)):
            steppers.home(axis)
            st = await steppers.wait_idle(axis, 60.0)  # 500 steps/s homing, up to a turn
            assert st.homed
            steppers.move_to(axis, target)
            st = await steppers.wait_idle(axis, steppers.move_time_s(axis, 45.0) + 2.0)
            half_step = 0.5 / steppers.axes[axis].steps_per_deg
            assert st.position_deg == pytest.approx(target, abs=half_step)
            assert not st.at_limit

    run(body)
