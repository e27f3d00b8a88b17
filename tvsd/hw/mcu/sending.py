"""McuLink's sending half: the message table, the typed frames, the heartbeats' bookkeeping.

Any thread may call these: each frame is packed here and handed whole to ``io_thread.LinkIo.send``
(one lock, non-blocking, never interleaved; False when the line cannot take it). A heartbeat's send
time goes into the receiver's ``hb_sent`` table *before* the frame goes, because its ack may come
back on the I/O thread before ``send`` returns; the receiver pairs each ack with it (round trips,
clock sync) and the scheduled heartbeat forgets the ones that will never come back.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable

from tvsd.errors import UsageError
from tvsd.hw.mcu.spec import ProtocolSpec

HB_FORGET_S = 2.0  # a heartbeat unanswered this long will never be (40 heartbeats at 50 ms)
HB_TABLE_CHECK = 64  # the table is swept for such heartbeats only once it holds more than this

# LinkIo.send: (message id, payload, tag for the refusal log) -> taken
SendFrame = Callable[[int, bytes, object], bool]


def host_us() -> int:
    """The heartbeat's stamp: the host's monotonic clock in µs, 32 bits as the frame carries it."""
    return int(time.monotonic() * 1e6) & 0xFFFF_FFFF


class Sender:
    """Packs and sends the host -> MCU messages of ``spec``; ``hb_sent`` is the receiver's table
    of heartbeats in flight (host_us -> send time)."""

    def __init__(self, spec: ProtocolSpec, send_frame: SendFrame, hb_sent: dict[int, float]) -> None:
        self._ids = {m.name: m for m in spec.messages}
        self._send_frame = send_frame
        self._hb_sent = hb_sent

    def message_id(self, name: str) -> int:
        return self._ids[name].id

    def send(self, name: str, *values: int) -> bool:
        """One message by its protocol.yaml name; a value its field cannot hold is a UsageError."""
        m = self._ids[name]
        try:
            payload = m.codec.pack(*values)
        except struct.error as exc:
            fields = ", ".join(f"{f.name}={v}" for f, v in zip(m.fields, values, strict=False))
            raise UsageError(f"cannot send {name}({fields}): {exc}") from exc
        return self._send_frame(m.id, payload, (name, values))

    # --- the typed frames ---------------------------------------------------------------------

    def pwm(self, duty: float) -> bool:
        """Motor duty in [-1, 1] (clamped; NaN means 0: a bad command must not spin the motor)."""
        if duty != duty:  # NaN
            duty = 0.0
        value = round(max(-1.0, min(1.0, duty)) * 32767)
        return self.send("pwm_set", value)

    def laser(self, on: bool) -> bool:
        return self.send("laser_set", 1 if on else 0)

    def stepper_move(self, axis: int, steps: int, rate_sps: int, accel_sps2: int) -> bool:
        return self.send("stepper_move", axis, steps, rate_sps, accel_sps2)

    def stepper_home(self, axis: int) -> bool:
        return self.send("stepper_home", axis)

    def config(self, watchdog_ms: int, state_div: int, max_on_ms: int) -> bool:
        return self.send("config_set", watchdog_ms, state_div, max_on_ms)

    # --- heartbeats -----------------------------------------------------------------------------

    def scheduled_heartbeat(self) -> bool:
        """The I/O thread's scheduled heartbeat (stamped now), after forgetting stale ones."""
        sent = self._hb_sent
        if len(sent) > HB_TABLE_CHECK:
            now = time.monotonic()
            for k, t in list(sent.items()):
                if now - t > HB_FORGET_S:
                    sent.pop(k, None)
        return self.heartbeat(host_us())

    def heartbeat(self, stamp: int) -> bool:
        """One heartbeat stamped ``stamp`` (host_us); False (and not in the table) if refused."""
        self._hb_sent[stamp] = time.monotonic()  # before the send: the ack may come first
        if self.send("heartbeat", stamp):
            return True
        self._hb_sent.pop(stamp, None)
        return False
