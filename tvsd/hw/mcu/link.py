"""McuLink: the serial link to the MCU on asyncio — transport, requests and dispatch.

It owns the port, the frames in both directions, the heartbeat (link watchdog, round trips for
the clock sync), the requests (identify, ping, stats) and the typed callbacks. Where a stamp lands
on the MCU's unwrapped tick count is not its business: it hands state, heartbeat_ack and pulse
stamps, and every frame loss it sees, to its ``TickPlacer`` (``placement``).

Reading: pyserial opens and configures the port; the event loop reads its descriptor with
``add_reader`` (as Moonraker's async_serial does) — no polling thread. Frames are decoded
incrementally and dispatched to typed callbacks.

Writing: every frame goes through one lock-protected, non-blocking ``os.write`` with a bounded
pending buffer, so the 10 kHz control thread can call ``send_pwm`` without touching the event
loop and without ever blocking; when the line cannot keep up, whole new frames are refused and
counted, never half-written.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import select
import statistics
import struct
import termios
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import serial

from tvsd.errors import DeviceError, ProtocolError, UsageError
from tvsd.hw.mcu.clock import ClockSync
from tvsd.hw.mcu.clock import warm_up as warm_up_clock_fit
from tvsd.hw.mcu.framing import FrameDecoder, encode_frame
from tvsd.hw.mcu.messages import (
    Ack,
    Fault,
    HeartbeatAck,
    Identify,
    McuStats,
    Pulse,
    State,
    StepperState,
    ack_meaning,
    check_against,
)
from tvsd.hw.mcu.placement import StateSample, TickPlacer
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import ProtocolSpec, load_spec

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

log = logging.getLogger(__name__)

FLASH_HINT = (
    "flash the firmware image of this tvsd (make -C firmware, then avrdude: hil/README.md, section MCU)"
)


def check_identity(ident: Identify, spec: ProtocolSpec, port: str) -> None:
    """Refuse an MCU that speaks another protocol: one line, seen vs expected, and the fix."""
    if ident.proto_version != spec.version:
        raise ProtocolError(
            f"the MCU on {port} speaks protocol v{ident.proto_version}, this tvsd speaks "
            f"v{spec.version}: {FLASH_HINT}"
        )
    if ident.table_hash != spec.table_hash:
        raise ProtocolError(
            f"the MCU on {port} has command table 0x{ident.table_hash:08X} (protocol "
            f"v{ident.proto_version}), this tvsd expects 0x{spec.table_hash:08X}: the firmware "
            f"was built from another protocol.yaml; {FLASH_HINT}"
        )


REFUSAL_LOG_INTERVAL_S = 1.0  # the same refusal is logged at most this often (with a count)


@dataclass(frozen=True, slots=True)
class PulseEvent:
    channel: int
    channel_name: str
    event_seq: int
    mcu_ticks: int  # unwrapped to 64 bits
    host_time: float  # clock-sync mapped; NaN before the first heartbeat round trip


@dataclass(frozen=True, slots=True)
class FaultEvent:
    code: int
    name: str
    detail: int
    host_time: float


@dataclass(frozen=True, slots=True)
class Refusal:
    """The MCU refused a frame we sent (an ack with a non-zero status)."""

    name: str  # message name, e.g. "stepper_move"
    values: tuple[int, ...]  # its fields, as sent
    status: int
    reason: str
    host_time: float


@dataclass
class LinkStats:
    frames_rx: int = 0
    frames_tx: int = 0
    crc_errors: int = 0
    bad_headers: int = 0
    resyncs: int = 0
    bytes_dropped: int = 0
    lost_frames: int = 0  # MCU -> host frames missing by SEQ gaps
    duplicates: int = 0
    lost_events: int = 0  # pulse events missing by event_seq gaps
    tx_dropped: int = 0  # host -> MCU frames refused because the output buffer was full
    nacks: int = 0  # ack frames with a non-zero status
    faults: int = 0
    link_up: bool = False
    link_losses: int = 0
    rtt_last_s: float = math.nan
    rtt_p50_s: float = math.nan
    rtt_max_s: float = math.nan
    rtt_samples: int = 0
    clock_drift_ppm: float = math.nan
    clock_residual_us: float = math.nan
    states_unanchored: int = 0  # state frames before the first heartbeat_ack that it could not place

    def as_dict(self) -> dict[str, Any]:
        return {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in self.__dict__.items()}


def open_serial(port: str, baud: int) -> serial.Serial:
    """Open the port non-blocking, or one clear DeviceError saying what to check."""
    try:
        return serial.Serial(port, baud, timeout=0, write_timeout=0, exclusive=True)
    except ValueError as exc:  # pyserial: a baud rate or setting it cannot apply
        raise UsageError(f"cannot open serial port {port} at {baud} baud: {exc}") from exc
    except (serial.SerialException, OSError) as exc:
        errno = getattr(exc, "errno", None)
        if errno:
            reason = os.strerror(errno)
        elif isinstance(exc.__context__, termios.error):  # opened, but termios refused it
            reason = f"not a serial port ({exc.__context__.args[-1]})"
        else:
            reason = str(exc)
        raise DeviceError(
            f"cannot open serial port {port}: {reason}; check the cable / the path / "
            "permissions (dialout group)"
        ) from exc


class McuLink:
    """One MCU on one serial port. Use ``async with McuLink(settings) as link`` (open, identify,
    heartbeat), or call open() / identify() / start_heartbeat() / close() yourself."""

    def __init__(
        self,
        settings: McuSettings,
        spec: ProtocolSpec | None = None,
        *,
        on_pulse: Callable[[PulseEvent], None] | None = None,
        on_state: Callable[[StateSample], None] | None = None,
        on_fault: Callable[[FaultEvent], None] | None = None,
        on_stepper: Callable[[StepperState], None] | None = None,
        on_link: Callable[[bool], None] | None = None,
        on_refused: Callable[[Refusal], None] | None = None,
    ) -> None:
        self.settings = settings
        self.spec = spec or load_spec(settings.spec_path)
        self._classes = check_against(self.spec)
        self._ids = {m.name: m for m in self.spec.messages}
        self.on_pulse, self.on_state, self.on_fault = on_pulse, on_state, on_fault
        self.on_stepper, self.on_link, self.on_refused = on_stepper, on_link, on_refused
        self.refusals: deque[Refusal] = deque(maxlen=64)
        self._refusal_log: dict[tuple[str, int], tuple[float, int]] = {}  # → (logged at, repeats since)
        self.identity: Identify | None = None
        self.clock: ClockSync | None = None
        self.steppers: dict[int, StepperState] = {}
        self.faults: deque[FaultEvent] = deque(maxlen=64)
        self._stats = LinkStats()
        self._decoder = FrameDecoder(self.spec.sync, self.spec.max_payload, self.spec.payload_sizes("m2h"))
        self._serial: serial.Serial | None = None
        self._fd: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        # transmit side: shared with the control thread
        self._tx_lock = threading.Lock()
        self._tx_pending = bytearray()
        self._tx_seq = 0
        self._tx_error: OSError | None = None
        # what went out under each SEQ: an ack names the frame by its SEQ only
        self._sent: list[tuple[str, tuple[int, ...]]] = [("", ())] * 0x1_0000
        # receive side: event-loop thread only
        self._last_rx = -math.inf
        self._watchdog: asyncio.TimerHandle | None = None
        self._hb_task: asyncio.Task[None] | None = None
        self._hb_sent: dict[int, float] = {}  # host_us -> send time
        self._hb_waiters: dict[int, asyncio.Future[float]] = {}
        self._identify_waiters: list[asyncio.Future[Identify]] = []
        self._stats_waiters: list[asyncio.Future[McuStats]] = []
        self._rtts: deque[float] = deque(maxlen=settings.rtt_history)
        self._placer = TickPlacer(self._deliver_state)
        self._event_seq: int | None = None
        handlers: dict[str, Callable[[Any, float], None]] = {
            "identify": self._on_identify,
            "heartbeat_ack": self._on_heartbeat_ack,
            "state": self._on_state,
            "pulse": self._on_pulse,
            "fault": self._on_fault,
            "stepper_state": self._on_stepper_state,
            "ack": self._on_ack,
            "stats": self._on_stats,
        }
        self._dispatch: dict[int, tuple[type, struct.Struct, Callable[[Any, float], None]]] = {
            self._ids[name].id: (self._classes[self._ids[name].id], self._ids[name].codec, h)
            for name, h in handlers.items()
        }

    # --- life cycle ---------------------------------------------------------------------------

    async def open(self) -> None:
        warm_up_clock_fit()  # while no heartbeat is due: the first fit costs tens of ms
        self._loop = asyncio.get_running_loop()
        self._serial = open_serial(self.settings.port, self.settings.baud)
        self._fd = self._serial.fileno()
        self._loop.add_reader(self._fd, self._on_readable)

    async def close(self) -> None:
        await self.stop_heartbeat()
        self._shutdown()

    def _shutdown(self) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
            self._watchdog = None
        with self._tx_lock:
            fd, self._fd = self._fd, None
        if fd is not None and self._loop is not None:
            self._loop.remove_reader(fd)
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

    # --- requests -----------------------------------------------------------------------------

    async def identify(self, attempts: int = 3) -> Identify:
        """Ask the MCU who it is; refuse a protocol version or command table other than ours."""
        loop = self._require_loop()
        ident: Identify | None = None
        for _ in range(attempts):  # the first request may land while the MCU is resyncing
            fut: asyncio.Future[Identify] = loop.create_future()
            self._identify_waiters.append(fut)
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
        self.clock = ClockSync(ident.clock_hz, self.settings.clock)
        return ident

    def restart_clock_sync(self) -> None:
        """Forget the heartbeat round trips: the MCU's clock restarted, jumped or was held (a
        SIL clock that starts running); the fit rebuilds from the next heartbeats."""
        if self.identity is not None:
            self.clock = ClockSync(self.identity.clock_hz, self.settings.clock)

    async def ping(self, timeout_s: float = 0.5) -> float:
        """One heartbeat round trip; returns the RTT in seconds."""
        loop = self._require_loop()
        fut: asyncio.Future[float] = loop.create_future()
        deadline = loop.time() + timeout_s
        while (host_us := self._send_heartbeat()) is None:  # output full: let it drain
            if self._fd is None or loop.time() > deadline:
                raise DeviceError(
                    f"cannot send to the MCU on {self.settings.port}: the link is closed or "
                    f"its output stayed full for {timeout_s} s"
                )
            await asyncio.sleep(0.001)
            self.flush()
        self._hb_waiters[host_us] = fut
        try:
            return await asyncio.wait_for(fut, max(0.0, deadline - loop.time()))
        except TimeoutError:
            raise DeviceError(
                f"the MCU on {self.settings.port} did not answer a heartbeat within {timeout_s} s"
            ) from None
        finally:
            self._hb_waiters.pop(host_us, None)

    async def request_stats(self, timeout_s: float = 0.5) -> McuStats:
        loop = self._require_loop()
        fut: asyncio.Future[McuStats] = loop.create_future()
        self._stats_waiters.append(fut)
        self._send("stats_req")
        try:
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            raise DeviceError(
                f"the MCU on {self.settings.port} did not answer stats_req within {timeout_s} s"
            ) from None

    async def stop_heartbeat(self) -> None:
        """Stop sending heartbeats: the MCU's watchdog then switches its outputs off."""
        if self._hb_task is not None:
            self._hb_task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._hb_task
            self._hb_task = None

    def start_heartbeat(self) -> None:
        if self._hb_task is None:
            self._hb_task = self._require_loop().create_task(self._heartbeat_loop())

    async def _heartbeat_loop(self) -> None:
        period = self.settings.heartbeat_period_s
        loop = self._require_loop()
        next_t = loop.time()
        while True:
            self._send_heartbeat()
            now = time.monotonic()
            # forget round trips that will never come back (2 s is 40 heartbeats)
            for k in [k for k, t in self._hb_sent.items() if now - t > 2.0]:
                del self._hb_sent[k]
            next_t += period
            await asyncio.sleep(max(0.0, next_t - loop.time()))

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

    def _send_heartbeat(self) -> int | None:
        now = time.monotonic()
        host_us = int(now * 1e6) & 0xFFFF_FFFF
        if not self._send("heartbeat", host_us):
            return None
        self._hb_sent[host_us] = now
        return host_us

    def _send(self, name: str, *values: int) -> bool:
        m = self._ids[name]
        try:
            payload = m.codec.pack(*values)
        except struct.error as exc:
            fields = ", ".join(f"{f.name}={v}" for f, v in zip(m.fields, values, strict=False))
            raise UsageError(f"cannot send {name}({fields}): {exc}") from exc
        with self._tx_lock:
            if self._fd is None:
                return False
            frame = encode_frame(self._tx_seq, m.id, payload, self.spec.sync)
            if len(self._tx_pending) + len(frame) > self.settings.tx_buffer_bytes:
                self._stats.tx_dropped += 1
                self._flush_locked()
                return False
            # SEQ only advances for frames that go out: a gap at the MCU is a loss on the wire
            self._sent[self._tx_seq] = (name, values)
            self._tx_seq = (self._tx_seq + 1) & 0xFFFF
            self._tx_pending += frame
            self._stats.frames_tx += 1
            self._flush_locked()
            return True

    def _flush_locked(self) -> None:
        fd = self._fd
        while self._tx_pending and fd is not None:
            try:
                n = os.write(fd, self._tx_pending)
            except BlockingIOError:
                return
            except OSError as exc:  # the device went away; the reader reports it
                self._tx_error = exc
                self._tx_pending.clear()
                return
            del self._tx_pending[:n]

    def flush(self) -> None:
        with self._tx_lock:
            self._flush_locked()

    # --- receiving (event-loop thread) --------------------------------------------------------

    def _on_readable(self) -> None:
        fd = self._fd
        if fd is None:
            return
        try:
            data = os.read(fd, 65536)
        except BlockingIOError:
            return
        except OSError as exc:
            self._device_gone(f"read failed: {exc.strerror}")
            return
        if not data:
            self._device_gone("end of file")
            return
        now = time.monotonic()
        if not self._stats.link_up:
            self._decoder.reset_sequence()  # a SEQ gap across an outage means nothing
        frames = self._decoder.feed(data)
        if frames:
            self._last_rx = self._require_loop().time()
            if not self._stats.link_up:
                self._set_link(True)
            if self._watchdog is None:
                self._arm_watchdog()
        for f in frames:
            self._placer.note_lost(f.gap)  # losses up to this frame, not the whole read's
            # the decoder only passes ids of m2h messages with their exact payload size
            cls, codec, handler = self._dispatch[f.msg_id]
            try:
                handler(cls(*codec.unpack(f.payload)), now)
            except Exception:  # a consumer's bug must not stop the link
                log.exception("MCU link: handler for %s failed", cls.__name__)
        if self._tx_pending:
            self.flush()

    def _device_gone(self, why: str) -> None:
        log.error("MCU link on %s: %s", self.settings.port, why)
        self._tx_error = self._tx_error or OSError(why)
        self._shutdown()
        if self._stats.link_up:
            self._set_link(False)

    def _set_link(self, up: bool) -> None:
        self._stats.link_up = up
        if not up:
            self._stats.link_losses += 1
        if self.on_link is not None:
            try:
                self.on_link(up)
            except Exception:
                log.exception("MCU link: on_link callback failed")

    def _arm_watchdog(self) -> None:
        # One timer per timeout period, re-armed from the last frame's time: a loss is seen
        # link_lost_ms after the last frame, without a timer per frame at 10 kHz.
        loop = self._require_loop()
        self._watchdog = loop.call_at(self._last_rx + self.settings.link_lost_s, self._check_link)

    def _check_link(self) -> None:
        self._watchdog = None
        if self._fd is None or not self._stats.link_up:
            return
        if self._require_loop().time() >= self._last_rx + self.settings.link_lost_s:
            # A host that was not scheduled for a while has not lost the link: read what is
            # waiting first (the timer can run before the reader in the loop's iteration). Only
            # if readable: with VMIN = VTIME = 0 an empty read returns b"", which means EOF.
            fd = self._fd
            if fd is not None and select.select([fd], [], [], 0)[0]:
                self._on_readable()
            if self._fd is None:
                return
        if self._require_loop().time() >= self._last_rx + self.settings.link_lost_s:
            # the 16-bit stamps cannot be chained across an outage: break the chain
            self._placer.note_lost(1)
            self._set_link(False)  # the next frame re-arms the watchdog
        elif self._watchdog is None:  # (reading may have re-armed it)
            self._arm_watchdog()

    def _on_identify(self, msg: Identify, now: float) -> None:
        for fut in self._identify_waiters:
            if not fut.done():
                fut.set_result(msg)
        self._identify_waiters.clear()

    def _on_heartbeat_ack(self, msg: HeartbeatAck, now: float) -> None:
        sent = self._hb_sent.pop(msg.host_us, None)
        ticks = self._placer.on_heartbeat_ack(msg.mcu_ticks, now)
        if sent is None:
            return  # an answer to a heartbeat we gave up on
        rtt = now - sent
        self._rtts.append(rtt)
        st = self._stats
        st.rtt_last_s = rtt
        st.rtt_samples += 1
        st.rtt_max_s = rtt if math.isnan(st.rtt_max_s) else max(st.rtt_max_s, rtt)
        if self.clock is not None:
            self.clock.add(sent, now, ticks)
        fut = self._hb_waiters.pop(msg.host_us, None)
        if fut is not None and not fut.done():
            fut.set_result(rtt)

    def _deliver_state(self, sample: StateSample) -> None:
        if self.on_state is not None:
            self.on_state(sample)

    def _on_state(self, msg: State, now: float) -> None:
        self._placer.on_state(msg.ticks, msg.encoder16, now, self.clock)

    def _on_pulse(self, msg: Pulse, now: float) -> None:
        # event_seq counts pulse events of all channels together (see the protocol notes)
        if self._event_seq is not None:
            gap = (msg.event_seq - self._event_seq - 1) & 0xFFFF
            if gap >= 0x8000:  # behind the last one: a repeat, not 65 000 losses
                return
            self._stats.lost_events += gap
        self._event_seq = msg.event_seq
        ticks = self._placer.unwrap32(msg.mcu_ticks)
        host = self.clock.to_host(ticks) if self.clock is not None else math.nan
        name = self.spec.pulse_channels.get(msg.channel, f"channel{msg.channel}")
        if self.on_pulse is not None:
            self.on_pulse(PulseEvent(msg.channel, name, msg.event_seq, ticks, host))

    def _on_fault(self, msg: Fault, now: float) -> None:
        name = self.spec.fault_codes.get(msg.code, f"fault{msg.code}")
        ev = FaultEvent(msg.code, name, msg.detail, now)
        self._stats.faults += 1
        self.faults.append(ev)
        log.warning("MCU fault %s (code %d, detail %d)", name, msg.code, msg.detail)
        if self.on_fault is not None:
            self.on_fault(ev)

    def _on_stepper_state(self, msg: StepperState, now: float) -> None:
        self.steppers[msg.axis] = msg
        if self.on_stepper is not None:
            self.on_stepper(msg)

    def _on_ack(self, msg: Ack, now: float) -> None:
        if msg.status == 0:
            return
        self._stats.nacks += 1
        name, values = self._sent[msg.seq]
        ref = Refusal(name or "?", values, msg.status, ack_meaning(msg.status), now)
        self.refusals.append(ref)
        # pwm_set goes with every state frame (1 kHz): while the outputs are disarmed each one is
        # refused. One line per kind per second, with the count, not a line per frame.
        key = (ref.name, msg.status)
        logged_at, repeats = self._refusal_log.get(key, (-math.inf, 0))
        if now - logged_at >= REFUSAL_LOG_INTERVAL_S:
            more = f" ({repeats} more like it since the last report)" if repeats else ""
            log.warning("MCU refused %s%s: %s%s", ref.name, ref.values, ref.reason, more)
            self._refusal_log[key] = (now, 0)
        else:
            self._refusal_log[key] = (logged_at, repeats + 1)
        if self.on_refused is not None:
            self.on_refused(ref)

    def _on_stats(self, msg: McuStats, now: float) -> None:
        for fut in self._stats_waiters:
            if not fut.done():
                fut.set_result(msg)
        self._stats_waiters.clear()

    # --- reporting ----------------------------------------------------------------------------

    @property
    def link_up(self) -> bool:
        return self._stats.link_up

    @property
    def tx_error(self) -> OSError | None:
        return self._tx_error

    def stats(self) -> LinkStats:
        """A snapshot of the counters."""
        d = self._decoder.stats
        st = self._stats
        st.frames_rx, st.crc_errors, st.bad_headers = d.frames, d.crc_errors, d.bad_headers
        st.resyncs, st.bytes_dropped = d.resyncs, d.bytes_dropped
        st.states_unanchored = self._placer.unanchored
        st.lost_frames, st.duplicates = d.lost_frames, d.duplicates
        if self._rtts:
            st.rtt_p50_s = statistics.median(self._rtts)
        fit = self.clock.fit_ if self.clock is not None else None
        if fit is not None:
            st.clock_drift_ppm, st.clock_residual_us = fit.drift_ppm, fit.residual_us
        with self._tx_lock:
            return LinkStats(**st.__dict__)

    def _require_loop(self) -> asyncio.AbstractEventLoop:
        if self._loop is None:
            raise RuntimeError("McuLink.open() has not run")
        return self._loop
