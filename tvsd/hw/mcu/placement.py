"""Tick placement: where the MCU's 32-bit stamps land on its unwrapped 64-bit tick count.

Protocol v2 stamps every frame that carries time (state, pulse, heartbeat_ack) with the MCU's full
32-bit tick count, which wraps every 2**32 / clock_hz (268 s at 16 MHz, 25.6 s at 168 MHz). A
stamp is unwrapped to the count nearest an estimate of the MCU's present count (the latest count
seen, moved on by the host time since at the nominal rate). That is right while the estimate is
off by less than half a wrap (134 s at 16 MHz), so a lost frame or an outage no longer breaks the
chain as v1's 16-bit state stamps (wrapping every 4.1 ms) did. The encoder count (16 bits on
the wire) is unwrapped across gaps from its last speed. ``TickPlacer`` does no I/O: the link
feeds it decoded messages and the frame losses it sees, and it hands back placed
``StateSample``s through one callback.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from tvsd.hw.mcu.clock import ClockSync, unwrap_nearest


@dataclass(frozen=True, slots=True)
class StateSample:
    mcu_ticks: int  # unwrapped to 64 bits (the low 32 bits came on the wire)
    encoder: int  # unwrapped encoder count
    host_time: float  # time.monotonic() of arrival
    # v1 flagged samples placed by guess after a loss; v2's 32-bit stamps place every one from
    # the MCU's own count, so it stays True (kept for the consumers that read it)
    exact: bool = True
    # no frame lost (by SEQ, of any kind) and no link outage since the previous state frame: the
    # host's late-input hold checks the MCU sent every frame (tvsd.control.hold)
    chained: bool = True


class TickPlacer:
    """Unwraps one MCU's stamps and encoder counts; placed state samples go to ``deliver``.

    Event-loop thread only. ``note_lost`` must be called with every frame loss (SEQ gaps) and
    once per link outage *before* the frame that follows it is handed over.
    """

    def __init__(self, deliver: Callable[[StateSample], None]) -> None:
        self._deliver = deliver
        self.unanchored = 0  # v1 held state frames before the first ack; v2 places them all
        self._ticks: int | None = None  # latest unwrapped MCU tick count
        self._ticks_host = 0.0
        self._state_ticks: int | None = None
        self._rx_lost = 0  # frames lost before the frame being handled (+1 per link outage)
        self._chain_lost = 0  # _rx_lost at the last state frame
        self._encoder: int | None = None
        self._enc_rate = 0.0  # counts per tick, to unwrap the encoder across gaps

    def note_lost(self, frames: int) -> None:
        """Frames lost before the next one (or 1 for an outage)."""
        self._rx_lost += frames

    def _reference(self, now: float, clock: ClockSync | None) -> int | None:
        """The MCU's count now, roughly: the latest count seen, moved on by the host time since
        at the nominal clock rate. Not the clock fit: a fit made while a SIL clock was held
        can be off by far more than the half wrap this reference may miss by."""
        if self._ticks is None:
            return None
        hz = clock.clock_hz if clock is not None else 0
        return self._ticks + int(max(0.0, now - self._ticks_host) * hz)

    def unwrap32(self, raw: int, now: float | None = None, clock: ClockSync | None = None) -> int:
        """A 32-bit stamp (state, pulse, heartbeat_ack) on the unwrapped count."""
        ref = self._ticks if now is None else self._reference(now, clock)
        if ref is None:
            return raw  # the first stamp: the count since the MCU started (mod 2**32)
        # stamps are at most seconds old: nearest is right while the reference is < 2**31 off
        return unwrap_nearest(raw, 32, ref)

    def on_heartbeat_ack(self, mcu_ticks: int, now: float) -> int:
        """Place a heartbeat_ack's stamp; returns it unwrapped."""
        ticks = self.unwrap32(mcu_ticks)
        if self._ticks is None or ticks > self._ticks:
            self._ticks, self._ticks_host = ticks, now
        return ticks

    def on_state(self, ticks32: int, encoder16: int, now: float, clock: ClockSync | None) -> None:
        """Place one state frame (``clock``: the link's current sync, for the unwrap reference)."""
        ticks = self.unwrap32(ticks32, now, clock)
        chained = self._rx_lost == self._chain_lost
        enc = encoder16
        prev = self._state_ticks
        if self._encoder is not None and prev is not None:
            # predicted from the last speed: right across gaps shorter than a 32768-count move
            dt = ticks - prev
            enc = unwrap_nearest(encoder16, 16, self._encoder + round(self._enc_rate * dt))
            if chained and dt > 0:
                self._enc_rate = (enc - self._encoder) / dt
        self._state_ticks, self._encoder, self._chain_lost = ticks, enc, self._rx_lost
        if self._ticks is None or ticks > self._ticks:
            self._ticks, self._ticks_host = ticks, now
        self._deliver(StateSample(ticks, enc, now, True, chained and prev is not None))
