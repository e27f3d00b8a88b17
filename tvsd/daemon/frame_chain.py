"""The chain of MCU state frames that the control thread's late-input hold judges.

On the link's I/O thread (DriveLink._on_state), each state frame is asked: nothing lost by SEQ
and no link outage since the previous one (`StateSample.chained`), and its stamp — the MCU's
tick count, taken in its tick ISR — exactly one state period of the MCU's clock after the
previous frame's, within half a control tick (a dropped MCU tick, a stall, a restart all break
it). A frame that continues the chain is *due* one period after the previous one's due time, and
never later than its arrival: a late burst's frames are due when the MCU sent them, whenever the
host's tty handed them over. One that breaks it starts a new chain (`chain_ns`: the arrival of
its first frame). The control kernel gets both with the measurement (tvsd.control.hold).
"""

from __future__ import annotations

from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.spec import CONTROL_TICK_HZ

# A frame's due time runs this much faster than the MCU's nominal clock (a crystal is within
# 100 ppm): over a 500 ms hold an error of 0.5 ms, and an MCU clock that is slow cannot make
# frames on time look late (an on-time frame brings `due` back to its arrival).
DUE_RATE_MARGIN = 1e-3


class FrameChain:
    """Due times and chain starts of one link's state frames (its I/O thread only)."""

    def __init__(self) -> None:
        self._prev_ticks: int | None = None
        self._due_ns = 0
        self.chain_ns = 0  # arrival of the current chain's first frame (CLOCK_MONOTONIC ns)
        self.breaks = 0  # frames that started a chain (the first one too)
        self.late_max_ns = 0  # the latest a frame arrived after it was due

    def due(self, s: StateSample, arrival_ns: int, clock_hz: float, state_div: int) -> int:
        """When the frame `s`, arrived at `arrival_ns`, was due (ns, ≤ the arrival)."""
        prev, self._prev_ticks = self._prev_ticks, s.mcu_ticks
        tick = clock_hz / CONTROL_TICK_HZ
        if s.chained and prev is not None and abs(s.mcu_ticks - prev - state_div * tick) * 2 < tick:
            step = (s.mcu_ticks - prev) * 1e9 / clock_hz * (1.0 + DUE_RATE_MARGIN)
            due = min(arrival_ns, self._due_ns + round(step))
        else:
            due = self.chain_ns = arrival_ns
            self.breaks += 1
        self._due_ns = due
        self.late_max_ns = max(self.late_max_ns, arrival_ns - due)
        return due
