"""CAN bridge to a robot (python-can): status at a fixed rate, points as they come, commands in.

Off by default (`CanSettings.enabled`). The frame layout is in `tvsd.hw.can.frames` and the
table for the robot's side in ``tvsd/hw/can/CAN.md``; in short, from the base id B (0x580):
B+0 COMMAND (robot→tvsd), B+1 ACK, B+2 STATUS (every 1/status_hz s), B+3 POINT (two frames a point).

Never blocks the event loop (STYLE.md §7):
- receive: a `can.Notifier` given the loop feeds a `can.AsyncBufferedReader` (it watches the bus's
  file descriptor with `add_reader` where the bus has one, e.g. socketcan, and otherwise reads in
  its own thread and hands over with `call_soon_threadsafe`, e.g. the virtual bus);
- send: one asyncio task sends frames through a one-thread executor, so a slow or full bus stalls
  that thread, not the loop. Acks and status go first; points wait in a bounded queue and, when the
  bus is slower than the scanner, the oldest point is dropped and counted (`stats.dropped`) — the
  robot wants the newest points, and latency stays bounded.
Frames from the robot that break the protocol (length, unknown code, out-of-range value) get a
refused ack with the reason and are counted (`stats.bad_frames`); nothing the robot sends raises.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import inspect
import logging
import time
from collections.abc import Awaitable, Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import can

from tvsd.errors import DeviceError
from tvsd.hw.can.frames import (
    OFF_ACK,
    OFF_COMMAND,
    OFF_POINT,
    OFF_STATUS,
    Ack,
    BadFrame,
    Command,
    CommandCode,
    Reason,
    decode_command,
    encode_ack,
    encode_point,
    encode_status,
    state_of,
)
from tvsd.hw.can.settings import CanSettings

__all__ = ["Ack", "CanBridge", "CanSettings", "CanStats", "Command", "CommandCode", "Reason"]

log = logging.getLogger(__name__)

CommandHandler = Callable[[Command], Awaitable[Ack]] | Callable[[Command], Ack]


@dataclass(frozen=True)
class CanStats:
    tx: int = 0  # frames sent
    rx: int = 0  # command frames received
    dropped: int = 0  # points dropped because the bus was slower than the scanner
    bad_frames: int = 0  # command frames that broke the protocol
    tx_errors: int = 0  # frames the bus refused to send (bus off, buffer full)


class CanBridge:
    def __init__(
        self, settings: CanSettings, on_command: CommandHandler, bus: can.BusABC | None = None
    ) -> None:
        self.settings = settings
        self._on_command = on_command
        self._bus = bus
        self._owns_bus = bus is None
        self._stats = CanStats()
        self._status: Mapping[str, Any] = {}
        self._status_seq = 0
        self._point_seq = 0
        self._urgent: collections.deque[can.Message] = collections.deque()  # acks, status
        self._points: collections.deque[tuple[bytes, bytes]] = collections.deque()
        self._wake = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self._notifier: can.Notifier | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._reader: _Reader | None = None
        self.running = False
        self.error: str | None = None  # why reception stopped (bus down), for the daemon's status

    @property
    def stats(self) -> CanStats:
        return self._stats

    def _count(self, **delta: int) -> None:
        self._stats = replace(self._stats, **{k: getattr(self._stats, k) + v for k, v in delta.items()})

    def _id(self, offset: int) -> int:
        return self.settings.base_id + offset

    async def start(self) -> None:
        """Open the bus (unless one was given) and start the tasks; a no-op when not enabled."""
        if not self.settings.enabled or self.running:
            return
        loop = asyncio.get_running_loop()
        self._wake = asyncio.Event()  # bound to this loop: start() may follow a close() in another
        self._urgent.clear()
        if self._bus is None:
            s = self.settings
            try:
                self._bus = can.Bus(interface=s.interface, channel=s.channel, bitrate=s.bitrate)
            except (can.CanError, OSError, ValueError, ImportError) as exc:
                raise DeviceError(
                    f"CAN bus {s.interface}:{s.channel} did not open ({exc}); check the interface is up "
                    f"(`ip link set {s.channel} up type can bitrate {s.bitrate}`) or set can.enabled: false"
                ) from exc
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="can-tx")
        # The loop goes to the Notifier: AsyncBufferedReader's own `loop` argument is deprecated and
        # ignored on Python ≥ 3.10. A short timeout lets a reader thread notice close() quickly.
        self._reader = _Reader(self)
        self._notifier = can.Notifier(self._bus, [self._reader], timeout=0.1, loop=loop)
        self.running = True
        self._tasks = [
            asyncio.create_task(self._rx_loop(), name="can-rx"),
            asyncio.create_task(self._tx_loop(), name="can-tx"),
            asyncio.create_task(self._status_loop(), name="can-status"),
        ]
        for task in self._tasks:
            task.add_done_callback(_log_death)

    async def close(self) -> None:
        if not self.running:
            return
        self.running = False
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        if self._notifier is not None:
            notifier, self._notifier = self._notifier, None
            if _has_fd(self._bus):
                notifier.stop(timeout=0)  # add_reader mode: nothing to join, must run on the loop
            else:  # reader thread: joining it takes up to the notifier timeout, so off the loop
                await asyncio.get_running_loop().run_in_executor(None, notifier.stop, 1.0)
        if self._executor is not None:  # let a send in progress finish before the bus goes
            executor, self._executor = self._executor, None
            await asyncio.to_thread(executor.shutdown, wait=True, cancel_futures=True)
        if self._owns_bus and self._bus is not None:
            self._bus.shutdown()
            self._bus = None

    # --- outgoing --------------------------------------------------------------------------------

    def publish_status(self, status: Mapping[str, Any]) -> None:
        """Latest daemon status (its status dict); sent at status_hz, so calling often is cheap."""
        self._status = status

    def publish_point(self, record: Mapping[str, Any]) -> None:
        """Queue one point record (tvsd.scan.points FIELDS); never blocks, drops the oldest if full."""
        if not self.running:
            return
        frames = encode_point(record, self._point_seq)
        self._point_seq = (self._point_seq + 1) & 0x7
        if len(self._points) >= self.settings.point_queue:
            self._points.popleft()
            self._count(dropped=1)
        self._points.append(frames)
        self._wake.set()

    def _status_frame(self) -> can.Message:
        s = self._status
        loop = s.get("loop")
        missed = s.get("missed_ticks", loop.get("missed_ticks", 0) if isinstance(loop, Mapping) else 0)
        faults = s.get("faults", 0)
        data = encode_status(
            state_of(s.get("state")),
            float(s.get("rps") or 0.0),
            len(faults) if isinstance(faults, (list, tuple)) else int(faults),
            int(missed),
            self._stats.dropped,
            self._status_seq,
        )
        self._status_seq = (self._status_seq + 1) & 0xFF
        return self._message(OFF_STATUS, data)

    def _message(self, offset: int, data: bytes) -> can.Message:
        return can.Message(arbitration_id=self._id(offset), data=data, is_extended_id=False)

    def _send_urgent(self, msg: can.Message) -> None:
        self._urgent.append(msg)
        self._wake.set()

    async def _status_loop(self) -> None:
        # Absolute deadlines (no drift); after a stall, skip the missed ticks rather than burst.
        period = 1.0 / self.settings.status_hz
        deadline = time.monotonic()
        while True:
            try:
                self._send_urgent(self._status_frame())
            except (TypeError, ValueError) as exc:  # a status dict of the wrong shape: a bug upstream
                log.warning("CAN status not sent: %s", exc)
            deadline += period
            now = time.monotonic()
            if deadline < now:
                deadline += period * ((now - deadline) // period + 1)
            await asyncio.sleep(deadline - now)

    async def _tx_loop(self) -> None:
        loop = asyncio.get_running_loop()
        while True:
            await self._wake.wait()
            self._wake.clear()
            while self._urgent or self._points:
                if self._urgent:
                    batch = [self._urgent.popleft()]
                else:  # both parts back to back, so nothing of ours comes between them
                    p0, p1 = self._points.popleft()
                    batch = [self._message(OFF_POINT, p0), self._message(OFF_POINT, p1)]
                sent = await loop.run_in_executor(self._executor, self._send_blocking, batch)
                self._count(tx=sent, tx_errors=len(batch) - sent)

    def _send_blocking(self, batch: list[can.Message]) -> int:
        """Runs in the tx thread: a full bus may make send() wait up to its timeout here."""
        assert self._bus is not None
        sent = 0
        for msg in batch:
            try:
                self._bus.send(msg, timeout=0.1)
                sent += 1
            except can.CanError as exc:
                log.debug("CAN send failed: %s", exc)
        return sent

    # --- incoming --------------------------------------------------------------------------------

    async def _rx_loop(self) -> None:
        assert self._reader is not None
        async for msg in self._reader:
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue  # not ours: other nodes may share the bus
            if msg.arbitration_id != self._id(OFF_COMMAND):
                continue
            self._count(rx=1)
            await self._handle(bytes(msg.data))

    async def _handle(self, data: bytes) -> None:
        try:
            cmd = decode_command(data)
        except BadFrame as exc:
            self._count(bad_frames=1)
            log.info("CAN: refused a bad command frame %s: %s", data.hex(), exc)
            self._send_urgent(
                self._message(OFF_ACK, encode_ack(exc.code, exc.cmd_id, Ack.refused(exc.reason)))
            )
            return
        ack = await self._call_handler(cmd)
        self._send_urgent(self._message(OFF_ACK, encode_ack(cmd.code, cmd.cmd_id, ack)))

    async def _call_handler(self, cmd: Command) -> Ack:
        try:
            result = self._on_command(cmd)
            if inspect.isawaitable(result):
                result = await asyncio.wait_for(result, self.settings.handler_timeout_s)
        except TimeoutError:
            return Ack.refused(Reason.TIMEOUT)
        except Exception:  # the robot gets an answer whatever the handler does; the bug is logged
            log.exception("CAN command handler failed on %s", cmd)
            return Ack.refused(Reason.INTERNAL)
        if not isinstance(result, Ack):
            log.error("CAN command handler returned %r, not an Ack", result)
            return Ack.refused(Reason.INTERNAL)
        return result


class _Reader(can.AsyncBufferedReader):
    """The bridge's listener: also told when the bus fails (e.g. the interface went down)."""

    def __init__(self, bridge: CanBridge) -> None:
        super().__init__()
        self._bridge = bridge

    def on_error(self, exc: Exception) -> None:
        self._bridge.error = f"CAN receive stopped: {exc}"
        log.error(
            "%s; check the interface (`ip -details link show`) and restart the bridge", self._bridge.error
        )


def _log_death(task: asyncio.Task[None]) -> None:
    if not task.cancelled() and task.exception() is not None:
        log.error("CAN bridge task %s died", task.get_name(), exc_info=task.exception())


def _has_fd(bus: can.BusABC | None) -> bool:
    if bus is None:
        return False
    with contextlib.suppress(NotImplementedError):
        return bus.fileno() >= 0
    return False
