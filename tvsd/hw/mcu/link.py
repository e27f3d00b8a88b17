"""McuLink: the serial link to the MCU — life cycle, requests and sending.

Three parts, one owner each: this module opens the port, runs the requests (identify, ping,
stats) for the event loop and offers the typed sends (any thread); ``io_thread.LinkIo`` owns the
port's descriptor on its own thread (reads, writes, the heartbeat that arms the firmware's
watchdog, the loss check); ``receiving.Receiver`` handles the frames on that thread and hands the
event loop what it must see through a bounded queue. Where a stamp lands on the MCU's unwrapped
tick count is the ``TickPlacer``'s business (``placement``).

Callbacks: ``on_state`` and ``on_batch`` run on the I/O thread (keep them short, allocate
little: they are the control thread's input); ``on_pulse``, ``on_fault``, ``on_stepper``,
``on_link`` and ``on_refused`` run on the event loop's thread.
"""

from __future__ import annotations

import asyncio
import statistics
import struct
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import serial

from tvsd.errors import DeviceError, ProtocolError, UsageError
from tvsd.hw.mcu.clock import ClockSync
from tvsd.hw.mcu.clock import warm_up as warm_up_clock_fit
from tvsd.hw.mcu.events import (
    FLASH_HINT,
    FaultEvent,
    LinkStats,
    PulseEvent,
    Refusal,
    check_identity,
    open_serial,
)
from tvsd.hw.mcu.framing import Frame, FrameDecoder
from tvsd.hw.mcu.io_thread import LinkIo
from tvsd.hw.mcu.messages import Identify, McuStats, StepperState
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.receiving import Receiver
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.shared_tx import SharedTx
from tvsd.hw.mcu.spec import ProtocolSpec, load_spec
from tvsd.hw.mcu.tty_worker_state import restore_stale
from tvsd.hw.mcu.tty_workers import TtyWorkerBoost, mode_from_env

__all__ = [
    "FLASH_HINT",
    "FaultEvent",
    "LinkStats",
    "McuLink",
    "McuSettings",
    "PulseEvent",
    "Refusal",
    "StateSample",
    "check_identity",
    "open_serial",
]

class _ReceiverCallback:
    """An ``on_*`` attribute of McuLink that is its receiver's (set after construction too)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, link: McuLink, owner: type | None = None) -> Any:
        return getattr(link._rx, self.name)

    def __set__(self, link: McuLink, value: Any) -> None:
        setattr(link._rx, self.name, value)


# what a link without its tty workers raised risks, for the status (siltiming.md)
TTY_RISK = "under CPU load the MCU's bytes may wait behind other programs (faults mcu_stale, mcu_watchdog)"
HB_FORGET_S = 2.0  # a heartbeat unanswered this long will never be (40 heartbeats at 50 ms)


class McuLink:
    """One MCU on one serial port. Use ``async with McuLink(settings) as link`` (open, identify,
    heartbeat), or call open() / identify() / start_heartbeat() / close() yourself.

    ``liveness``: a count the heartbeat schedule checks (the control kernel's ticks): a
    heartbeat goes only if it moved since the last one. ``io_priority``: SCHED_FIFO for the I/O
    thread (``--realtime``). ``shared_tx``: the port's write side shared with the control kernel
    (``Runner.tx``), which then sends the heartbeats itself (``kernel_heartbeats``)."""

    on_pulse = _ReceiverCallback()
    on_state = _ReceiverCallback()
    on_batch = _ReceiverCallback()
    on_fault = _ReceiverCallback()
    on_stepper = _ReceiverCallback()
    on_link = _ReceiverCallback()
    on_refused = _ReceiverCallback()

    def __init__(
        self,
        settings: McuSettings,
        spec: ProtocolSpec | None = None,
        *,
        on_pulse: Callable[[PulseEvent], None] | None = None,
        on_state: Callable[[StateSample], None] | None = None,
        on_batch: Callable[[], None] | None = None,
        on_fault: Callable[[FaultEvent], None] | None = None,
        on_stepper: Callable[[StepperState], None] | None = None,
        on_link: Callable[[bool], None] | None = None,
        on_refused: Callable[[Refusal], None] | None = None,
        liveness: Callable[[], int] | None = None,
        io_priority: int | None = None,
        shared_tx: SharedTx | None = None,
        state_dir: Path | None = None,
    ) -> None:
        self.settings = settings
        self.spec = spec or load_spec(settings.spec_path)
        self._ids = {m.name: m for m in self.spec.messages}
        self.identity: Identify | None = None
        self._stats = LinkStats()
        self._decoder = FrameDecoder(self.spec.sync, self.spec.max_payload, self.spec.payload_sizes("m2h"))
        self._serial: serial.Serial | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._io = LinkIo(
            settings,
            self.spec.sync,
            self._decoder,
            self._stats,
            on_frames=self._frames,
            on_link=self._link_change,
            on_gone=self._gone,
            heartbeat=self._heartbeat,
            liveness=liveness,
            priority=io_priority,
            shared=shared_tx,
        )
        self._rx = Receiver(
            self.spec,
            self._stats,
            self._io.sent,
            settings.rtt_history,
            on_pulse=on_pulse,
            on_state=on_state,
            on_batch=on_batch,
            on_fault=on_fault,
            on_stepper=on_stepper,
            on_link=on_link,
            on_refused=on_refused,
        )
        # --realtime: the kernel's tty workers too, which hand every received byte to the reader
        # (tvsd.hw.mcu.tty_workers: preempted, they held the MCU's frames up to 1.2 s); what it
        # changes is kept in `state_dir` (the daemon's runtime dir) for a daemon killed meanwhile
        self._state_dir = state_dir
        self._tty_mode = mode_from_env(settings.tty_workers) if io_priority is not None else None
        mode = self._tty_mode
        self._tty_workers = TtyWorkerBoost(mode, state_dir=state_dir) if mode not in (None, "off") else None

    # the receiver's handlers, looked up at call time (a test may stand in for one)
    def _frames(self, frames: list[Frame], now: float) -> None:
        self._rx.on_frames(frames, now)

    def _link_change(self, up: bool) -> None:
        self._rx.on_link_change(up)

    def _gone(self, why: str) -> None:
        self._rx.on_gone(f"{self.settings.port}: {why}")

    # --- life cycle ---------------------------------------------------------------------------

    async def open(self) -> None:
        warm_up_clock_fit()  # while no heartbeat is due: the first fit costs tens of ms
        self._loop = asyncio.get_running_loop()
        self._rx.attach(self._loop)
        if self._state_dir is not None:  # an earlier daemon's, killed before it put them back
            restore_stale(self._state_dir)  # (a few small files on a tmpfs and /proc: µs)
        self._serial = open_serial(self.settings.port, self.settings.baud)
        if self._tty_workers is not None:
            self._tty_workers.start()
        self._io.start(self._serial.fileno())

    async def close(self) -> None:
        await self.stop_heartbeat()
        self._io.stop()
        if self._tty_workers is not None:
            self._tty_workers.stop()
        if self._state_dir is not None:  # a daemon killed while this one ran: it kept them raised
            restore_stale(self._state_dir)  # (not awaited: close may run while being cancelled)
        if self._serial is not None:
            self._serial.close()
            self._serial = None

    async def __aenter__(self) -> McuLink:
        await self.open()
        try:
            await self.identify()
            # one round trip before returning: it arms the MCU's watchdog (outputs are refused
            # until a heartbeat) and gives the clock sync its first sample
            await self.ping()
        except BaseException:
            await self.close()
            raise
        self.start_heartbeat()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # --- requests (event loop) ----------------------------------------------------------------

    async def identify(self, attempts: int = 3) -> Identify:
        """Ask the MCU who it is; refuse a protocol version or command table other than ours."""
        loop = self._require_loop()
        ident: Identify | None = None
        for _ in range(attempts):  # the first request may land while the MCU is resyncing
            fut: asyncio.Future[Identify] = loop.create_future()
            self._rx.identify_waiters.append(fut)
            self._send("identify_req")
            try:
                ident = await asyncio.wait_for(fut, self.settings.identify_timeout_s / attempts)
                break
            except TimeoutError:
                continue
        if ident is None:
            raise DeviceError(
                f"no answer from the MCU on {self.settings.port} within "
                f"{self.settings.identify_timeout_s} s: is the firmware flashed, the board "
                f"powered and the baud rate ({self.settings.baud}) the firmware's?"
            )
        check_identity(ident, self.spec, self.settings.port)
        if ident.clock_hz == 0:
            raise ProtocolError("MCU reports a clock of 0 Hz: its identify frame is wrong")
        self.identity = ident
        self._rx.clock = ClockSync(ident.clock_hz, self.settings.clock)
        return ident

    @property
    def clock(self) -> ClockSync | None:
        return self._rx.clock

    def restart_clock_sync(self) -> None:
        """Forget the heartbeat round trips: the MCU's clock restarted, jumped or was held (a
        SIL clock that starts running); the fit rebuilds from the next heartbeats."""
        if self.identity is not None:
            self._rx.clock = ClockSync(self.identity.clock_hz, self.settings.clock)

    async def ping(self, timeout_s: float = 0.5) -> float:
        """One heartbeat round trip; returns the RTT in seconds."""
        loop = self._require_loop()
        fut: asyncio.Future[float] = loop.create_future()
        deadline = loop.time() + timeout_s
        host_us = self._host_us()
        self._rx.hb_waiters[host_us] = fut  # before the send: the answer comes on another thread
        try:
            while not self._send_heartbeat(host_us):  # output full: let it drain
                if self._io.fd is None or loop.time() > deadline:
                    raise DeviceError(
                        f"cannot send to the MCU on {self.settings.port}: the link is closed or "
                        f"its output stayed full for {timeout_s} s"
                    )
                await asyncio.sleep(0.001)
                self.flush()
            return await asyncio.wait_for(fut, max(0.0, deadline - loop.time()))
        except TimeoutError:
            raise DeviceError(
                f"the MCU on {self.settings.port} did not answer a heartbeat within {timeout_s} s"
            ) from None
        finally:
            self._rx.hb_waiters.pop(host_us, None)

    async def request_stats(self, timeout_s: float = 0.5) -> McuStats:
        loop = self._require_loop()
        fut: asyncio.Future[McuStats] = loop.create_future()
        self._rx.stats_waiters.append(fut)
        self._send("stats_req")
        try:
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            raise DeviceError(
                f"the MCU on {self.settings.port} did not answer stats_req within {timeout_s} s"
            ) from None

    async def stop_heartbeat(self) -> None:
        """Stop sending heartbeats: the MCU's watchdog then switches its outputs off."""
        self._io.heartbeats(False)

    def kernel_heartbeats(self, on: bool) -> None:
        """The control kernel sends the heartbeats (Runner.attach_link on ``shared_tx``): the
        I/O thread's schedule pauses, and the kernel's acks feed the round trips and the clock
        sync. Off: the I/O thread's schedule (if started) takes over again."""
        self._rx.kernel_heartbeats = on
        self._io.kernel_heartbeats(on)

    def start_heartbeat(self) -> None:
        """Heartbeats every settings.heartbeat_period_s from the I/O thread (while ``liveness``
        moves), the first one now."""
        self._io.heartbeats(True)

    # --- sending (any thread) -----------------------------------------------------------------

    def send_pwm(self, duty: float) -> bool:
        """Motor duty in [-1, 1] (clamped; NaN means 0: a bad command must not spin the motor).
        Safe from any thread, never blocks; False if the frame was refused."""
        if duty != duty:  # NaN
            duty = 0.0
        value = round(max(-1.0, min(1.0, duty)) * 32767)
        return self._send("pwm_set", value)

    def send_laser(self, on: bool) -> bool:
        return self._send("laser_set", 1 if on else 0)

    def send_stepper_move(self, axis: int, steps: int, rate_sps: int, accel_sps2: int) -> bool:
        return self._send("stepper_move", axis, steps, rate_sps, accel_sps2)

    def send_stepper_home(self, axis: int) -> bool:
        return self._send("stepper_home", axis)

    def send_config(self, watchdog_ms: int, state_div: int, max_on_ms: int) -> bool:
        return self._send("config_set", watchdog_ms, state_div, max_on_ms)

    @staticmethod
    def _host_us() -> int:
        return int(time.monotonic() * 1e6) & 0xFFFF_FFFF

    def _heartbeat(self) -> bool:
        """The I/O thread's scheduled heartbeat."""
        sent = self._rx.hb_sent
        if len(sent) > 64:  # forget round trips that will never come back
            now = time.monotonic()
            for k, t in list(sent.items()):
                if now - t > HB_FORGET_S:
                    sent.pop(k, None)
        return self._send_heartbeat(self._host_us())

    def _send_heartbeat(self, host_us: int) -> bool:
        self._rx.hb_sent[host_us] = time.monotonic()  # before the send: the ack may come first
        if self._send("heartbeat", host_us):
            return True
        self._rx.hb_sent.pop(host_us, None)
        return False

    def _send(self, name: str, *values: int) -> bool:
        m = self._ids[name]
        try:
            payload = m.codec.pack(*values)
        except struct.error as exc:
            fields = ", ".join(f"{f.name}={v}" for f, v in zip(m.fields, values, strict=False))
            raise UsageError(f"cannot send {name}({fields}): {exc}") from exc
        return self._io.send(m.id, payload, (name, values))

    def flush(self) -> None:
        self._io.flush()

    # --- reporting ----------------------------------------------------------------------------

    @property
    def link_up(self) -> bool:
        return self._stats.link_up

    @property
    def tx_error(self) -> OSError | None:
        return self._io.tx_error

    def message_id(self, name: str) -> int:
        return self._ids[name].id

    @property
    def shared_tx(self) -> SharedTx:
        """The port's write side (its byte counters; the control kernel's when it was given)."""
        return self._io.shared

    @property
    def io_realtime(self) -> str:
        """What the I/O thread's SCHED_FIFO request got ("not requested" without one)."""
        return self._io.realtime

    @property
    def tty_workers(self) -> str:
        """What raising the kernel's tty workers got (tvsd.hw.mcu.tty_workers; --realtime only).
        Refused or off under --realtime, it says what that risks (`tvsctl status` shows it)."""
        if self._tty_mode is None:
            return "not requested"
        if self._tty_workers is None:
            return f"off (mcu.tty_workers): {TTY_RISK}"
        status = self._tty_workers.status
        return f"{status}: {TTY_RISK}" if status.startswith("refused") else status

    @property
    def steppers(self) -> dict[int, StepperState]:
        return self._rx.steppers

    @property
    def faults(self) -> list[FaultEvent]:
        return list(self._rx.faults)

    @property
    def refusals(self) -> list[Refusal]:
        return list(self._rx.refusals)

    def stats(self) -> LinkStats:
        """A snapshot of the counters."""
        d = self._decoder.stats
        st = self._stats
        st.frames_rx, st.crc_errors, st.bad_headers = d.frames, d.crc_errors, d.bad_headers
        st.resyncs, st.bytes_dropped = d.resyncs, d.bytes_dropped
        st.states_unanchored = self._rx.placer.unanchored
        st.lost_frames, st.duplicates = d.lost_frames, d.duplicates
        rtts = list(self._rx.rtts)
        if rtts:
            st.rtt_p50_s = statistics.median(rtts)
        clock = self._rx.clock
        fit = clock.fit_ if clock is not None else None
        if fit is not None:
            st.clock_drift_ppm, st.clock_residual_us = fit.drift_ppm, fit.residual_us
        return LinkStats(**st.__dict__)

    def reset_peaks(self) -> None:
        """Zero the worst cases (heartbeat gap and lateness): they then cover what follows."""
        self._stats.heartbeat_gap_max_s = self._stats.heartbeat_late_max_s = 0.0

    def _require_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise RuntimeError("McuLink.open() has not run")
        return self._loop
