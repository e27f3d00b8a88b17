"""Tick placement: where the MCU's truncated stamps land on its unwrapped 64-bit tick count.

The wire carries 16-bit state stamps (``ticks16``), 16-bit encoder counts and 32-bit pulse and
heartbeat_ack stamps. ``TickPlacer`` owns everything needed to unwrap them: the chain of state
frames anchored at the last heartbeat_ack, the samples held before the first ack (their epoch is
unknown until it comes), placement from the clock fit after a loss, and the encoder's unwrapping
across gaps. It does no I/O: the link feeds it decoded messages and the frame losses it sees, and
it hands back placed ``StateSample``s through one callback.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from tvsd.hw.mcu.clock import ClockSync, unwrap_nearest

# A state frame may be stamped a little after a heartbeat_ack it follows in the queue (the tick
# ISR can run between the ack's timestamp and its frame_send): 64 µs at 16 MHz is ample.
ACK_SLACK_TICKS = 1024
# After a loss the 16-bit stamp is placed from the clock fit: a frame is stamped before it arrives,
# so its count is the latest one with those low bits at or before the arrival mapped to MCU ticks,
# plus this much for the fit's own error (0.5 ms); right while the frame's latency is under
# 4.1 ms - 0.5 ms (one ticks16 wrap minus the slack).
GUESS_SLACK_TICKS = 8000
# State frames that come before the first heartbeat_ack (their epoch unknown) are held, then
# placed by that ack and delivered exact; at 10 kHz this is 0.4 s of them.
HOLD_MAX = 4096


@dataclass(frozen=True, slots=True)
class StateSample:
    mcu_ticks: int  # unwrapped to 64 bits (the low 16 bits came on the wire)
    encoder: int  # unwrapped encoder count
    host_time: float  # time.monotonic() of arrival
    # unwrapped along an unbroken chain of frames from a heartbeat_ack; False after a loss or an
    # outage until the next ack (mcu_ticks placed from the clock fit, possibly off by multiples of
    # 65536). Frames before the first ack are held and delivered when it places them (exact).
    exact: bool = True


class TickPlacer:
    """Unwraps one MCU's stamps and encoder counts; placed state samples go to ``deliver``.

    Event-loop thread only. ``note_lost`` must be called with every frame loss (SEQ gaps) and
    once per link outage *before* the frame that follows it is handed over.
    """

    def __init__(self, deliver: Callable[[StateSample], None]) -> None:
        self._deliver = deliver
        self.unanchored = 0  # state frames before the first heartbeat_ack that it could not place
        self._ticks: int | None = None  # latest unwrapped MCU tick count
        self._ticks_host = 0.0
        self._state_ticks: int | None = None
        self._anchor_ticks: int | None = None  # last state or heartbeat_ack stamp (ticks16 base)
        self._anchor_lost = 0  # _rx_lost at that anchor
        self._anchor_exact = False  # the anchor descends from a heartbeat_ack
        self._rx_lost = 0  # frames lost before the frame being handled (+1 per link outage)
        self._held: deque[StateSample] = deque()  # state samples before the first heartbeat_ack
        self._acked = False  # a heartbeat_ack has fixed the tick count's epoch
        self._encoder: int | None = None
        self._enc_rate = 0.0  # counts per tick, to unwrap the encoder across gaps

    def note_lost(self, frames: int) -> None:
        """Frames lost before the next one (or 1 for an outage): breaks the ticks16 chain."""
        self._rx_lost += frames

    def unwrap32(self, raw: int) -> int:
        """A 32-bit stamp (pulse, heartbeat_ack) on the unwrapped count."""
        if self._ticks is None:
            return raw
        # events are stamped at most seconds in the past: nearest is right while < 2**31 ticks
        return unwrap_nearest(raw, 32, self._ticks)

    def on_heartbeat_ack(self, mcu_ticks: int, now: float) -> int:
        """Anchor on a heartbeat_ack's full stamp; returns it unwrapped. Releases held samples."""
        ticks = self.unwrap32(mcu_ticks)
        self._ticks, self._ticks_host = ticks, now  # the full counter is authoritative
        lost = self._rx_lost
        # The MCU queues frames in order: the last state frame received was stamped before this
        # ack, and the next one after it, give or take an ISR (ACK_SLACK_TICKS), and the state
        # period is capped below one ticks16 wrap. With no frame lost in between, both are exact.
        chained = self._state_ticks is not None and lost == self._anchor_lost
        if chained and self._state_ticks is not None:
            top = ticks + ACK_SLACK_TICKS
            placed = top - ((top - self._state_ticks) & 0xFFFF)
            self._release_held(placed - self._state_ticks)
            self._state_ticks = placed
        self._release_held(None)  # not chained to this ack: their epoch stays unknown
        self._acked = True
        self._anchor_ticks, self._anchor_lost = ticks - ACK_SLACK_TICKS, lost
        self._anchor_exact = True
        return ticks

    def on_state(self, ticks16: int, encoder16: int, now: float, clock: ClockSync | None) -> None:
        """Place one state frame (``clock``: the link's current sync, for placement after a loss)."""
        # ticks16 is the low half of the MCU's tick counter (16 MHz: it wraps every 4.1 ms; the
        # firmware caps the state period at 4 ms): unwrap it forward from the last state frame
        # or heartbeat_ack, as long as no frame was lost since.
        lost = self._rx_lost
        anchor = self._anchor_ticks
        chained = anchor is not None and lost == self._anchor_lost
        # exact only along a chain that starts at a heartbeat_ack: before the first one the
        # count's upper bits (and so its epoch) are unknown
        exact = chained and self._anchor_exact
        if anchor is not None and chained:
            ticks = anchor + ((ticks16 - anchor) & 0xFFFF)
        elif self._ticks is not None and self._acked:
            # After a loss, place it from the clock (flagged: a latency over ~3.6 ms makes it a
            # wrap off); the next heartbeat_ack restores the exact count.
            ticks = self._place_after_loss(ticks16, now, clock)
        else:
            ticks = ticks16
        self._anchor_ticks, self._anchor_lost, self._anchor_exact = ticks, lost, exact
        enc = encoder16
        prev = self._state_ticks
        if self._encoder is not None and prev is not None:
            # predicted from the last speed: right across gaps shorter than a 32768-count move
            dt = ticks - prev
            enc = unwrap_nearest(encoder16, 16, self._encoder + round(self._enc_rate * dt))
            if chained and dt > 0:
                self._enc_rate = (enc - self._encoder) / dt
        self._state_ticks, self._encoder = ticks, enc
        sample = StateSample(ticks, enc, now, exact)
        if not self._acked:
            # Before the first heartbeat_ack the count's upper bits are unknown: hold the samples
            # (only an unbroken chain can be placed by the ack; a loss drops those before it).
            if not chained:
                self._release_held(None)
            self._held.append(sample)
            if len(self._held) > HOLD_MAX:
                self._held.popleft()
                self.unanchored += 1
            return
        if exact and ticks > (self._ticks or 0):
            self._ticks, self._ticks_host = ticks, now
        self._deliver(sample)

    def _release_held(self, shift: int | None) -> None:
        """Deliver the held pre-ack samples moved by `shift` ticks (exact), or drop them."""
        held, self._held = self._held, deque()
        if shift is None:
            self.unanchored += len(held)
            return
        for s in held:
            self._deliver(StateSample(s.mcu_ticks + shift, s.encoder, s.host_time, True))

    def _place_after_loss(self, ticks16: int, now: float, clock: ClockSync | None) -> int:
        """The count of a state frame that follows a loss: the latest with these low bits that
        was stamped before the frame arrived (clock fit, else the last count and the host clock),
        and after the last stamp seen."""
        if clock is not None and clock.fit_ is not None:
            latest = clock.to_ticks(now) + GUESS_SLACK_TICKS
        else:
            hz = clock.clock_hz if clock is not None else 0
            assert self._ticks is not None
            latest = self._ticks + int(max(0.0, now - self._ticks_host) * hz) + GUESS_SLACK_TICKS
        ticks = latest - ((latest - ticks16) & 0xFFFF)
        if self._anchor_ticks is not None and ticks <= self._anchor_ticks:
            ticks += (((self._anchor_ticks - ticks) >> 16) + 1) << 16  # frames come in order
        return ticks
