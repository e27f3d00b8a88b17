"""The firmware core, built for the host, as a simulated chip: its clock, its UART's queues and the
plant's side of its pins. No transport: :class:`tvsd.sim.virtual_mcu.VirtualMcu` puts it behind a
pty and pumps the bytes.

Who owns what: this module the core's time, the host bytes queued for their core time, the TX
backlog, the encoder, pulses and limit switches in, PWM, laser and steppers out;
:mod:`tvsd.sim.vmcu_library` the library it loads; :mod:`tvsd.sim.mcu_wire` the wire model it
calls under its lock.

Time: the core counts 16 MHz ticks (62.5 ns, the ATmega328P's Timer1 at F_CPU/1), the unit of
every ``mcu_ticks`` on the wire. With ``clock="wall"`` the transport's pump advances the core to
the monotonic clock (about every millisecond); with ``clock="manual"`` only :meth:`advance_to`,
:meth:`set_shaft` and :meth:`pulse` move it, so a SIL plant can step it deterministically.

Plant side: :meth:`set_shaft` turns a shaft angle into the encoder count (``counts_per_rev``
quadrature counts per revolution) and a zero pulse at each whole revolution crossed (time
interpolated between calls); :meth:`pulse` latches a sensor edge; :attr:`pwm_duty`,
:attr:`motor_volts`, :attr:`laser_on` and :meth:`stepper_position` read the outputs back.

The UART drains the core's TX ring while time runs: every advance is cut into slices of at most
:data:`UART_SLICE_S` (at 2 Mbaud the line moves 200 bytes per millisecond; 10 kHz state frames
make 100), and the ring is emptied after each slice. So a long step of the clock (a manual
advance, or the pump thread woken late on a loaded host) does not overflow the ring (8 KB in the
host build: 82 ms of 10 kHz state frames), as it would not on the chip, whose UART never stops.

Not modelled: the UART's 2 Mbaud line rate (the pty is faster; the core's TX ring still drops
and counts frames when the reader falls behind by more than the pty buffer).
"""

from __future__ import annotations

import ctypes
import math
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Literal

from tvsd.sim.mcu_wire import WireModel, WireStats
from tvsd.sim.vmcu_library import VirtualMcuError, default_library, load_library

PULSE_ZERO = 0
PULSE_OPTICAL = 1
STEPPER_AXES = 2
_DUTY_FULL = 32767
PTY_BACKLOG = 65536  # bytes held for a slow reader before the core's TX ring takes the loss
UART_SLICE_S = 0.001  # longest stretch of core time between two drains of its TX ring


class McuCore:
    """The firmware core on a simulated clock, with the plant's inputs and outputs; the transport
    (:class:`tvsd.sim.virtual_mcu.VirtualMcu`) calls the ``_locked`` methods under ``_lock``."""

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
        # What the core's UART sent and the transport has not written yet (guarded by _lock:
        # advances fill it, the transport empties it).
        self._backlog = bytearray()
        self._txbuf = (ctypes.c_uint8 * 4096)()
        self._slice_ticks = max(1, round(UART_SLICE_S * self.clock_hz))
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
        while len(self._backlog) < PTY_BACKLOG:
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

    # ---- host bytes in (the transport hands them over) ------------------------------------
    def _rx_in_locked(self, when: int, arrival: float, data: bytes, heartbeat: bool = False) -> None:
        if self._rx_queue or when > int(self._lib.vmcu_now()):
            self._rx_queue.append((when, arrival, data, heartbeat))  # ahead of the core: later
        else:
            self._rx_locked(when, arrival, data, heartbeat)

    def _receive_locked(
        self, data: bytes, arrival: float, timeline: Callable[[float], float] | None, at: float
    ) -> None:
        """Host bytes read at `arrival` (time.monotonic) into the core, or queued for their core
        time (lock held). `timeline`: host time -> core seconds (:meth:`_timeline`, taken before
        the lock), `at` = timeline(arrival) (NaN: pacing not begun). With a timeline, a heartbeat
        goes in at its own send time (the wire model), the rest at `at`; without, now."""
        if timeline is not None and math.isfinite(at):
            hb_len = self._wire.heartbeat_frame_len
            for sent, part in self._wire.sent_times(data, arrival):
                if sent < arrival:  # a part that ends with a heartbeat: that frame alone
                    when, n = self._ticks(timeline(sent)), min(hb_len, len(part))
                    if len(part) > n:
                        self._rx_in_locked(when, arrival, part[:-n])
                    self._rx_in_locked(when, arrival, part[-n:], heartbeat=True)
                else:
                    self._rx_in_locked(self._ticks(at), arrival, part)
        else:
            self._rx_in_locked(-1, arrival, data)

    # ---- host time <-> core time (the wire model's lines, tvsd.sim.mcu_wire) ------------------
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

    def _release(self) -> None:
        """Remove the library copy's directory. The copy stays mapped until the process ends:
        ctypes has no unload."""
        shutil.rmtree(self._tmpdir, ignore_errors=True)
