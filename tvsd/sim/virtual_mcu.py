"""Virtual MCU: the real firmware core, built for the host, behind a real pseudo-terminal.

The same C core that runs on the ATmega328P (``firmware/core``), compiled with a host board
layer into a shared library and loaded with ctypes. Who owns what:

- this module: the core's clock, the plant's inputs and outputs, and the pty with the pump
  thread that moves bytes between it and the core;
- :mod:`tvsd.sim.vmcu_library`: finding, building (tests, developers) and loading the library
  (its names, and :class:`VirtualMcuError`, are importable from here too);
- :mod:`tvsd.sim.mcu_wire`: the wire model (heartbeats' send times, the watchdog cut held at its
  edge for the pty's late hand-over), called by this module under its lock.

A thread pumps
bytes between a pty and the core, so anything that opens :attr:`VirtualMcu.port` with pyserial
talks to the firmware's own parser, command table, watchdog and stepper planner, byte for byte.
A paced plant writes the core's output itself after each step (:meth:`VirtualMcu.write_out`):
the pump's select() waits for the kernel's tty flip-buffer worker, which CPU load delays.

Time: the core counts 16 MHz ticks (62.5 ns, the ATmega328P's Timer1 at F_CPU/1), the unit of
every ``mcu_ticks`` on the wire. With ``clock="wall"`` the pump thread advances the core to the
monotonic clock (about every millisecond); with ``clock="manual"`` only :meth:`advance_to`,
:meth:`set_shaft` and :meth:`pulse` move it, so a SIL plant can step it deterministically.

Plant side: :meth:`set_shaft` turns a shaft angle into the encoder count (``counts_per_rev``
quadrature counts per revolution) and a zero pulse at each whole revolution crossed (time
interpolated between calls); :meth:`pulse` latches a sensor edge; :attr:`pwm_duty`,
:attr:`motor_volts`, :attr:`laser_on` and :meth:`stepper_position` read the outputs back.

The UART drains the core's TX ring while time runs: every advance is cut into slices of at most
:data:`_UART_SLICE_S` (at 2 Mbaud the line moves 200 bytes per millisecond; 10 kHz state frames
make 100), and the ring is emptied after each slice. So a long step of the clock (a manual
advance, or the pump thread woken late on a loaded host) does not overflow the ring (8 KB in the
host build: 82 ms of 10 kHz state frames), as it would not on the chip, whose UART never stops.

Not modelled: the UART's 2 Mbaud line rate (the pty is faster; the core's TX ring still drops
and counts frames when the reader falls behind by more than the pty buffer).
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import os
import select
import shutil
import threading
import time
import tty
from collections import deque
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Literal

from tvsd.sim.mcu_wire import WireModel, WireStats
from tvsd.sim.vmcu_library import (
    FIRMWARE_DIR,
    LIBRARY,
    PACKAGED_MODULE,
    VirtualMcuError,
    build_library,
    default_library,
    load_library,
    packaged_library,
)

# The library's names stay importable from here, where callers and tests have always found them.
__all__ = [
    "FIRMWARE_DIR",
    "LIBRARY",
    "PACKAGED_MODULE",
    "PULSE_OPTICAL",
    "PULSE_ZERO",
    "STEPPER_AXES",
    "VirtualMcu",
    "VirtualMcuError",
    "build_library",
    "default_library",
    "packaged_library",
]

PULSE_ZERO = 0
PULSE_OPTICAL = 1
STEPPER_AXES = 2
_DUTY_FULL = 32767
_PUMP_PERIOD_S = 0.001
_PTY_BACKLOG = 65536  # bytes held for a slow reader before the core's TX ring takes the loss
_UART_SLICE_S = 0.001  # longest stretch of core time between two drains of its TX ring


class VirtualMcu:
    """The firmware core on a pty. Use as a context manager, or call :meth:`close`."""

    def __init__(
        self,
        *,
        counts_per_rev: int = 4096,
        drive_volts: float = 12.0,
        clock: Literal["wall", "manual"] = "wall",
        library: Path | None = None,
        wire_allowance_s: float = 0.0,
    ) -> None:
        """`wire_allowance_s` > 0: the wire model (tvsd.sim.mcu_wire) on a clock that runs on wall
        time (the wall clock, or a paced plant's timelines): the watchdog's cut waits at its edge
        for a heartbeat the pty may still hand over late, at most that long. 0: none (the pty's
        timing decides, as before; a manual clock driven by hand never waits)."""
        if counts_per_rev <= 0:
            raise VirtualMcuError(f"counts_per_rev must be positive, got {counts_per_rev}")
        if clock not in ("wall", "manual"):
            raise VirtualMcuError(f"clock must be 'wall' or 'manual', got {clock!r}")
        self.counts_per_rev = counts_per_rev
        self.drive_volts = drive_volts
        self.clock = clock
        if not 0.0 <= wire_allowance_s < 10.0:
            raise VirtualMcuError(f"wire_allowance_s must be in [0, 10) s, got {wire_allowance_s}")
        self.wire_allowance_s = wire_allowance_s
        self.wire = WireStats()  # what the wire model saw (tvsd.sim.mcu_wire)
        self._lib, self._tmpdir = load_library(library or default_library())
        self._lib.vmcu_init()
        self.clock_hz: int = self._lib.vmcu_clock_hz()
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self._shaft: tuple[float, float] | None = None  # last (t_s, angle_rad)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # bytes pass untouched: no echo, no line discipline
        os.set_blocking(self._master, False)
        self.port: str = os.ttyname(self._slave)
        self._backlog = bytearray()  # guarded by _lock (the pump writes it, advances fill it)
        self._txbuf = (ctypes.c_uint8 * 4096)()
        self._slice_ticks = max(1, round(_UART_SLICE_S * self.clock_hz))
        self._stop = threading.Event()
        self._closed = False
        self.cable_cut = False  # fault injection: both directions lost, the core runs on
        # (time.monotonic() of arrival, duty) of each PWM change the host's bytes made, when
        # enabled (log_pwm): a paced plant applies each from its arrival, as a motor would.
        self._pwm_log: list[tuple[float, float]] | None = None
        self._logged_pwm = 0
        # Manual clock: host time (time.monotonic) -> core seconds, set by a paced plant
        # (McuPlant.start). Host bytes then enter the core at their arrival's time on that line,
        # not at whatever time the core has reached when the pump reads them: a plant that fell
        # behind and catches up runs through the heartbeats that came meanwhile in order, instead
        # of getting them all at its stale time and then a gap the wire never had (the
        # firmware's watchdog expired on it). (core ticks, arrival, bytes), in arrival order.
        self.rx_timeline: Callable[[float], float] | None = None
        # Its inverse (core seconds -> host time): where the wire model's allowance is counted.
        self.core_to_host: Callable[[float], float] | None = None
        # (core ticks, arrival, bytes, a heartbeat frame alone), in arrival order.
        self._rx_queue: deque[tuple[int, float, bytes, bool]] = deque()
        self._wire = WireModel(self._lib, self.clock_hz, wire_allowance_s, self.wire)
        self._thread = threading.Thread(target=self._pump, name="virtual-mcu", daemon=True)
        self._thread.start()

    # ---- time ---------------------------------------------------------------------------
    def _ticks(self, t_s: float) -> int:
        return max(0, round(t_s * self.clock_hz))

    @property
    def time_s(self) -> float:
        """The core's simulated time, seconds since power-on."""
        with self._lock:
            return int(self._lib.vmcu_now()) / self.clock_hz

    @property
    def power_on_monotonic(self) -> float:
        """time.monotonic() at power-on: with the wall clock, core time = monotonic − this."""
        return self._t0

    def _wall_s(self) -> float:
        return time.monotonic() - self._t0

    def _now_or(self, t_s: float | None) -> float:
        if t_s is not None:
            return t_s
        return self._wall_s() if self.clock == "wall" else self.time_s

    def advance_to(self, t_s: float) -> None:
        """Run the core up to t_s (manual clock only; the wall clock runs by itself)."""
        if self.clock != "manual":
            raise VirtualMcuError("advance_to() drives the manual clock; this one is 'wall'")
        with self._lock:
            self._advance_locked(self._ticks(t_s))

    def _advance_locked(self, ticks: int) -> None:
        """Run the core to `ticks` in UART slices, draining its TX ring after each, and the
        queued host bytes in at their times (lock held)."""
        now = int(self._lib.vmcu_now())
        queue = self._rx_queue
        while queue and queue[0][0] <= now:
            self._rx_locked(*queue.popleft())
        # the wire model, only where this advance reaches the watchdog's edge (one call, not one a slice)
        wire = self._wire.reaches_edge(ticks)
        while now < ticks:
            now = min(ticks, now + self._slice_ticks)
            if queue and queue[0][0] < now:
                now = queue[0][0]  # stop where the next host bytes arrived
            if wire:
                self._wire.defer(now, queue, self._to_host())
            self._lib.vmcu_advance_to(now)
            while queue and queue[0][0] <= now:
                self._rx_locked(*queue.popleft())
            self._drain_locked()

    def flush_rx(self) -> None:
        """Host bytes still queued for a later core time go in now (the plant stopped)."""
        with self._lock:
            while self._rx_queue:
                self._rx_locked(*self._rx_queue.popleft())

    def _rx_locked(self, when: int, arrival: float, data: bytes, heartbeat: bool = False) -> None:
        """Host bytes into the core's UART (lock held); a PWM change they made is logged with
        their arrival time. A heartbeat frame alone that comes while the watchdog's cut waits for
        the wire is handled at `when`, its send tick: the watchdog counts from when it was on the
        wire, not from the pty's late hand-over (vmcu_rx_bytes_at; only a heartbeat, whose
        handling is a stamp)."""
        raw = (ctypes.c_uint8 * len(data)).from_buffer_copy(data)
        if heartbeat and self._wire.heartbeat_in(when):
            self._lib.vmcu_rx_bytes_at(raw, len(data), when)
        else:
            self._lib.vmcu_rx_bytes(raw, len(data))
        if self._pwm_log is not None:
            pwm = int(self._lib.vmcu_pwm())
            if pwm != self._logged_pwm:
                self._pwm_log.append((arrival, pwm / _DUTY_FULL))
                self._logged_pwm = pwm

    def _drain_locked(self) -> None:
        # Leave bytes in the core's TX ring when the reader is this far behind: the ring then
        # overflows and the firmware counts the loss, as on the real line.
        buf = self._txbuf
        while len(self._backlog) < _PTY_BACKLOG:
            n = self._lib.vmcu_tx_bytes(buf, len(buf))
            if not n:
                break
            self._backlog += bytes(buf[:n])

    # ---- plant inputs -------------------------------------------------------------------
    def set_shaft(self, angle_rad: float, t_s: float | None = None) -> None:
        """Shaft at angle_rad (unwrapped) at t_s: the encoder reads the new count from t_s on,
        and a zero pulse is latched for every multiple of 2*pi crossed since the last call, at
        the time interpolated linearly between them. Between two calls the encoder moves
        linearly on the manual clock (the ticks in between have not run yet: a real encoder
        counts all the way) and holds on the wall clock (they have)."""
        t = self._now_or(t_s)
        prev = self._shaft
        self._shaft = (t, angle_rad)
        counts = angle_rad / math.tau * self.counts_per_rev
        with self._lock:
            if prev is not None and self.clock == "manual":
                # first: the zero pulses below advance the core through part of the ramp
                c_prev = prev[1] / math.tau * self.counts_per_rev
                self._lib.vmcu_encoder_ramp(self._ticks(prev[0]), c_prev, self._ticks(t), counts)
            if prev is not None:
                t_prev, a_prev = prev
                lo, hi = sorted((a_prev, angle_rad))
                first, last = math.floor(lo / math.tau) + 1, math.floor(hi / math.tau)
                for k in range(first, last + 1):
                    frac = (k * math.tau - a_prev) / (angle_rad - a_prev)
                    t_k = t_prev + frac * (t - t_prev)
                    self._pulse_locked(PULSE_ZERO, self._ticks(t_k))
            if self.clock == "manual":
                # up to the tick before t: the control tick at t itself samples the new count
                self._advance_locked(self._ticks(t) - 1)
            count = round(counts)
            self._lib.vmcu_set_encoder(((count + 2**31) % 2**32) - 2**31)  # wraps like the chip

    def pulse(self, channel: int = PULSE_OPTICAL, t_s: float | None = None) -> None:
        """A sensor edge latched at t_s (default: now), timestamped in 62.5 ns ticks."""
        if channel not in (PULSE_ZERO, PULSE_OPTICAL):
            raise VirtualMcuError(f"pulse channel must be 0 (zero) or 1 (optical), got {channel}")
        t = self._now_or(t_s)
        with self._lock:
            self._pulse_locked(channel, self._ticks(t))

    def _pulse_locked(self, channel: int, ticks: int) -> None:
        if self.clock == "manual":
            self._advance_locked(ticks)  # the core latches at `ticks`, advancing there first
        self._lib.vmcu_pulse(channel, ticks)

    def set_limit(self, axis: int, position: int | None) -> None:
        """Home switch of a stepper axis: closed at and below `position` steps (None: absent)."""
        self._check_axis(axis)
        with self._lock:
            self._lib.vmcu_set_limit(axis, position is not None, position or 0)

    # ---- outputs ------------------------------------------------------------------------
    @property
    def pwm_duty(self) -> float:
        """Motor PWM duty, -1..1 (sign = H-bridge direction)."""
        with self._lock:
            return int(self._lib.vmcu_pwm()) / _DUTY_FULL

    def log_pwm(self) -> None:
        """From now on, note when each PWM change from the host arrived (see pwm_changes)."""
        with self._lock:
            self._pwm_log, self._logged_pwm = [], int(self._lib.vmcu_pwm())

    def pwm_changes(self) -> tuple[list[tuple[float, float]], float]:
        """The PWM changes the host's frames made since the last call, as (time.monotonic() of
        arrival, duty), and the duty now (which also shows the firmware's own cuts)."""
        with self._lock:
            log = self._pwm_log or []
            if self._pwm_log is not None:
                self._pwm_log = []
            return log, int(self._lib.vmcu_pwm()) / _DUTY_FULL

    @property
    def motor_volts(self) -> float:
        """Voltage the H-bridge applies to the motor: duty times drive_volts."""
        return self.pwm_duty * self.drive_volts

    @property
    def laser_on(self) -> bool:
        with self._lock:
            return bool(self._lib.vmcu_laser())

    def stepper_position(self, axis: int) -> int:
        """Where the mechanism is, in steps, counted from the pulses the firmware emitted."""
        self._check_axis(axis)
        with self._lock:
            return int(self._lib.vmcu_stepper_position(axis))

    def step_count(self, axis: int) -> int:
        self._check_axis(axis)
        with self._lock:
            return int(self._lib.vmcu_step_count(axis))

    @staticmethod
    def _check_axis(axis: int) -> None:
        if not 0 <= axis < STEPPER_AXES:
            raise VirtualMcuError(f"stepper axis must be 0..{STEPPER_AXES - 1}, got {axis}")

    # ---- byte pump ----------------------------------------------------------------------
    def _pump(self) -> None:
        while not self._stop.is_set():
            readable, _, _ = select.select([self._master], [], [], _PUMP_PERIOD_S)
            data = b""
            if readable:
                try:
                    data = os.read(self._master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError:  # pty gone (closing)
                    return
            arrival = time.monotonic()  # before the lock: a plant holding it does not delay it
            timeline = self._timeline()
            at = math.nan if timeline is None or not data else timeline(arrival)
            with self._lock:
                # Time first: received bytes are handled at the time they arrived, so a
                # heartbeat_ack's mcu_ticks matches the host's clock to the pump's latency.
                if self.clock == "wall":
                    self._advance_locked(self._ticks(self._wall_s()))
                if self.cable_cut:  # a cut cable: what the host sends never arrives (nor ours:
                    data = b""  # _write_locked drops it)
                if data and timeline is not None and math.isfinite(at):  # NaN: pacing not begun
                    hb_len = self._wire.heartbeat_frame_len
                    for sent, part in self._wire.sent_times(data, arrival):
                        if sent < arrival:  # a part that ends with a heartbeat: that frame alone
                            when, n = self._ticks(timeline(sent)), min(hb_len, len(part))
                            if len(part) > n:
                                self._rx_in_locked(when, arrival, part[:-n])
                            self._rx_in_locked(when, arrival, part[-n:], heartbeat=True)
                        else:
                            self._rx_in_locked(self._ticks(at), arrival, part)
                elif data:
                    self._rx_in_locked(-1, arrival, data)
                if not self._write_locked():
                    return

    def _rx_in_locked(self, when: int, arrival: float, data: bytes, heartbeat: bool = False) -> None:
        if self._rx_queue or when > int(self._lib.vmcu_now()):
            self._rx_queue.append((when, arrival, data, heartbeat))  # ahead of the core: later
        else:
            self._rx_locked(when, arrival, data, heartbeat)

    # ---- the wire model (tvsd.sim.mcu_wire) ---------------------------------------------------
    def _timeline(self) -> Callable[[float], float] | None:
        """Host time -> core seconds: a paced plant's line, or the wall clock's own."""
        if self.rx_timeline is not None:
            return self.rx_timeline
        if self.clock == "wall" and self.wire_allowance_s > 0:
            return lambda t: t - self._t0
        return None

    def _to_host(self) -> Callable[[float], float] | None:
        if self.core_to_host is not None:
            return self.core_to_host
        if self.clock == "wall" and self.wire_allowance_s > 0:
            return lambda t_s: self._t0 + t_s
        return None

    def write_out(self) -> None:
        """What the core has sent so far, to the pty now (non-blocking; the rest waits in the
        backlog): a paced plant calls it after its steps (McuPlant), so its state frames never
        wait for the pump thread. That thread can be held in its select() for as long as the
        kernel's tty flip-buffer work (a normal-priority kworker that every poll and read of a pty
        waits for: n_tty_poll, tty_buffer_flush_work) is kept from running: under 2 CPU hogs up to
        30 ms, and no state frame went out meanwhile and the daemon's control thread latched "MCU state
        frames stopped" (mcu.link_timeout_ms 40 ms). A write never waits for it."""
        with self._lock:
            self._write_locked()

    def _write_locked(self) -> bool:
        """Drain the core's TX ring and write the backlog (lock held); False once the pty is gone."""
        self._drain_locked()
        if self.cable_cut:  # a cut cable: nothing of ours reaches the host (the plant writes too)
            while self._backlog:  # what the core sent, and what a drain of a full ring adds
                self._backlog.clear()
                self._drain_locked()
            return True
        if self._backlog:  # non-blocking; under the lock, as advances append to it
            try:
                written = os.write(self._master, self._backlog)
                del self._backlog[:written]
            except (BlockingIOError, InterruptedError):
                pass
            except OSError:
                return False
        return True

    # ---- lifetime -----------------------------------------------------------------------
    def close(self) -> None:
        """Stop the pump thread and close the pty (idempotent). The library copy stays mapped
        until the process ends: ctypes has no unload."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join(timeout=2.0)
        for fd in (self._master, self._slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        shutil.rmtree(self._tmpdir, ignore_errors=True)

    def __enter__(self) -> VirtualMcu:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
