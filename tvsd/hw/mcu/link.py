"""McuLink: the serial link to the MCU — the public object: wiring, life cycle, reporting.

Five parts, one owner each: this module builds the others and opens and closes the port, and
is the one object callers hold; ``io_thread.LinkIo`` owns the port's descriptor on its own thread
(reads, writes, the heartbeat that arms the firmware's watchdog, the loss check);
``receiving.Receiver`` handles the frames on that thread and hands the event loop what it must
see through a bounded queue; ``sending.Sender`` packs the typed frames (any thread) and keeps
the heartbeats in flight; ``queries.Queries`` runs the requests the event loop awaits (identify,
ping, stats). Where a stamp lands on the MCU's unwrapped tick count is the ``TickPlacer``'s
business (``placement``).

Callbacks: ``on_state`` and ``on_batch`` run on the I/O thread (keep them short, allocate
little: they are the control thread's input); ``on_pulse``, ``on_fault``, ``on_stepper``,
``on_link`` and ``on_refused`` run on the event loop's thread.
"""

from __future__ import annotations

import asyncio
import statistics
from collections.abc import Callable
from pathlib import Path
from typing import Any

import serial

from tvsd.hw.mcu.clock import ClockSync
from tvsd.hw.mcu.clock import warm_up as warm_up_clock_fit
from tvsd.hw.mcu.events import FaultEvent, LinkStats, PulseEvent, Refusal, open_serial
from tvsd.hw.mcu.framing import Frame, FrameDecoder
from tvsd.hw.mcu.io_thread import LinkIo
from tvsd.hw.mcu.messages import Identify, McuStats, StepperState
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.queries import Queries
from tvsd.hw.mcu.receiving import Receiver
from tvsd.hw.mcu.sending import Sender
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.shared_tx import SharedTx
from tvsd.hw.mcu.spec import ProtocolSpec, load_spec
from tvsd.hw.mcu.tty_worker_state import restore_stale
from tvsd.hw.mcu.tty_workers import TtyWorkerBoost, describe, mode_from_env


class _ReceiverCallback:
    """An ``on_*`` attribute of McuLink that is its receiver's (set after construction too)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, link: McuLink, owner: type | None = None) -> Any:
        return getattr(link._rx, self.name)

    def __set__(self, link: McuLink, value: Any) -> None:
        setattr(link._rx, self.name, value)


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
            heartbeat=self._scheduled_heartbeat,
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
        self._tx = Sender(self.spec, self._io.send, self._rx.hb_sent)
        self._queries = Queries(settings, self.spec, self._rx, self._tx, self._io)
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

    def _scheduled_heartbeat(self) -> bool:
        return self._tx.scheduled_heartbeat()

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
        ident = await self._queries.identify(self._require_loop(), attempts)
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
        return await self._queries.ping(self._require_loop(), timeout_s)

    async def request_stats(self, timeout_s: float = 0.5) -> McuStats:
        return await self._queries.stats(self._require_loop(), timeout_s)

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
        return self._tx.pwm(duty)

    def send_laser(self, on: bool) -> bool:
        return self._tx.laser(on)

    def send_stepper_move(self, axis: int, steps: int, rate_sps: int, accel_sps2: int) -> bool:
        return self._tx.stepper_move(axis, steps, rate_sps, accel_sps2)

    def send_stepper_home(self, axis: int) -> bool:
        return self._tx.stepper_home(axis)

    def send_config(self, watchdog_ms: int, state_div: int, max_on_ms: int) -> bool:
        return self._tx.config(watchdog_ms, state_div, max_on_ms)

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
        return self._tx.message_id(name)

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
        return describe(self._tty_mode, self._tty_workers)

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
