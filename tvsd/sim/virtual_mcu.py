"""Virtual MCU: the real firmware core, built for the host, behind a real pseudo-terminal.

The same C core that runs on the ATmega328P (``firmware/core``) is compiled with a host board
layer into a shared library and loaded here with ctypes: in a source checkout
``firmware/build/libtvsmcu_host.so`` (``make -C firmware host-lib``; the top Makefile's ``run`` and
``pytest`` build it), in an installed wheel ``tvsd/sim/_vmcu*.so`` (compiled by setup.py when the
wheel was built). It is never built while tvsd runs. A thread pumps
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
import importlib.util
import math
import os
import select
import shutil
import subprocess
import tempfile
import threading
import time
import tty
import zlib
from collections import deque
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Literal

from tvsd.errors import DeviceError
from tvsd.hw.mcu.spec import FRAME_CRC, FRAME_HEADER, load_spec
from tvsd.sim.mcu_wire import WireStats

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
LIBRARY = FIRMWARE_DIR / "build" / "libtvsmcu_host.so"  # the checkout's (make -C firmware host-lib)
PACKAGED_MODULE = "tvsd.sim._vmcu"  # the wheel's (setup.py's build_ext)

PULSE_ZERO = 0
PULSE_OPTICAL = 1
STEPPER_AXES = 2
_DUTY_FULL = 32767
_PUMP_PERIOD_S = 0.001
_PTY_BACKLOG = 65536  # bytes held for a slow reader before the core's TX ring takes the loss
_UART_SLICE_S = 0.001  # longest stretch of core time between two drains of its TX ring
_HB_MAX_AGE_US = 1_000_000  # a heartbeat's host_us older than this at its read: not trusted


class VirtualMcuError(DeviceError):
    """The virtual MCU cannot be built, loaded or used as asked."""


def packaged_library() -> Path | None:
    """The core compiled into the installed package (a ctypes library: never imported)."""
    try:
        found = importlib.util.find_spec(PACKAGED_MODULE)
    except (ImportError, ValueError):
        return None
    return Path(found.origin) if found is not None and found.origin else None


def default_library() -> Path:
    """The library to load: the checkout's build when this is a source checkout, else the wheel's.

    Raises VirtualMcuError with the fix when neither exists (nothing is compiled here)."""
    if (FIRMWARE_DIR / "Makefile").is_file():  # a source checkout
        if LIBRARY.is_file():
            return LIBRARY
        packaged = packaged_library()
        if packaged is not None and packaged.is_file():
            return packaged  # `pip install -e .` compiled it from these sources
        raise VirtualMcuError(
            f"the virtual MCU library {LIBRARY} is not built. Fix: make -C {FIRMWARE_DIR} host-lib "
            "(or `make run` / `make test`, which build it)"
        )
    packaged = packaged_library()
    if packaged is not None and packaged.is_file():
        return packaged
    raise VirtualMcuError(
        f"this tvsd install has no virtual MCU library ({PACKAGED_MODULE.replace('.', '/')}*.so): "
        "the wheel was built without it. Fix: reinstall from a wheel built on a machine with a C "
        "compiler (pip wheel . in the source tree; README, Installing on the scanner)"
    )


def build_library(path: Path = LIBRARY) -> Path:
    """Build the checkout's library with ``make -C firmware host-lib`` if it is missing: for the
    test suite and developers, never called by tvsd itself."""
    if path.exists():
        return path
    missing = [tool for tool in ("make", "gcc") if shutil.which(tool) is None]
    if missing:
        raise VirtualMcuError(
            f"{path} is missing and cannot be built: {', '.join(missing)} not found. "
            "Fix: install the build tools (apt-get install build-essential), or run "
            "`make -C firmware host-lib` on a machine that has them and copy the library."
        )
    proc = subprocess.run(
        ["make", "-C", str(FIRMWARE_DIR), "host-lib"], capture_output=True, text=True, check=False
    )
    if proc.returncode != 0 or not path.exists():
        raise VirtualMcuError(
            f"building {path} failed (make -C {FIRMWARE_DIR} host-lib, status "
            f"{proc.returncode}):\n{proc.stderr.strip()[-2000:]}"
        )
    return path


def _load(path: Path) -> tuple[ctypes.CDLL, Path]:
    """Load a private copy of the library: the core is a singleton per loaded image, and a
    copy under another name gets its own, so several virtual MCUs can live in one process."""
    tmpdir = Path(tempfile.mkdtemp(prefix="tvsmcu-"))
    copy = tmpdir / path.name
    shutil.copyfile(path, copy)
    try:
        lib = ctypes.CDLL(str(copy))
    except OSError as exc:
        shutil.rmtree(tmpdir, ignore_errors=True)
        raise VirtualMcuError(f"cannot load {path}: {exc}. Fix: make -C firmware clean host-lib") from exc
    u8, u64, i32 = ctypes.c_uint8, ctypes.c_uint64, ctypes.c_int32
    buf = ctypes.POINTER(ctypes.c_uint8)
    for name, res, args in (
        ("vmcu_init", None, []),
        ("vmcu_clock_hz", ctypes.c_uint32, []),
        ("vmcu_now", u64, []),
        ("vmcu_advance_to", None, [u64]),
        ("vmcu_rx_bytes", None, [buf, ctypes.c_size_t]),
        ("vmcu_rx_bytes_at", None, [buf, ctypes.c_size_t, u64]),
        ("vmcu_watchdog", ctypes.c_int, [ctypes.POINTER(u64), ctypes.POINTER(u64)]),
        ("vmcu_watchdog_defer", None, [ctypes.c_int]),
        ("vmcu_watchdog_check", None, []),
        ("vmcu_tx_bytes", ctypes.c_size_t, [buf, ctypes.c_size_t]),
        ("vmcu_set_encoder", None, [i32]),
        ("vmcu_encoder_ramp", None, [u64, ctypes.c_double, u64, ctypes.c_double]),
        ("vmcu_pulse", None, [u8, u64]),
        ("vmcu_set_limit", None, [u8, ctypes.c_int, i32]),
        ("vmcu_pwm", ctypes.c_int16, []),
        ("vmcu_laser", ctypes.c_int, []),
        ("vmcu_stepper_position", i32, [u8]),
        ("vmcu_step_count", ctypes.c_uint32, [u8]),
    ):
        fn = getattr(lib, name)
        fn.restype = res
        fn.argtypes = args
    return lib, tmpdir


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
        self.wire = WireStats()
        self._lib, self._tmpdir = _load(library or default_library())
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
        self._wd_edge, self._wd_ticks = ctypes.c_uint64(), ctypes.c_uint64()
        self._released_edge = -1  # an edge the allowance ran out at: crossed
        self._deferring, self._held_since = False, 0.0  # the cut waits for the wire, since (monotonic)
        spec = load_spec()
        hb = spec.by_name("heartbeat")
        self._hb_head = (spec.sync, hb.size, hb.id)  # a heartbeat frame's SYNC, LEN, ID
        self._rx_tail = b""  # the last bytes read: a heartbeat split across two reads
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
        wire = self.wire_allowance_s > 0 and (
            self._deferring
            or (self._lib.vmcu_watchdog(self._wd_edge, self._wd_ticks) and ticks >= self._wd_edge.value)
        )
        while now < ticks:
            now = min(ticks, now + self._slice_ticks)
            if queue and queue[0][0] < now:
                now = queue[0][0]  # stop where the next host bytes arrived
            if wire:
                self._defer_locked(now)
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
        if (
            heartbeat
            and self._deferring
            and self._lib.vmcu_watchdog(self._wd_edge, self._wd_ticks)
            and when >= self._wd_edge.value  # sent at or after the edge: the host's own gap
        ):
            self._end_deferral_locked(released=False)
            self._lib.vmcu_watchdog_check()  # the cut, as the tick at the edge made it: before it
        if heartbeat and self._deferring and when >= 0:
            # read while the cut waits for it: the next edge counts from its send tick. (Not
            # otherwise: the ack's mcu_ticks stays the read's, as before, for the host's clock sync.)
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
                    hb_len = FRAME_HEADER + self._hb_head[1] + FRAME_CRC
                    for sent, part in self._sent_times(data, arrival):
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

    def _edge_locked(self) -> int | None:
        """The tick from which the watchdog's cut waits for the wire, or None (lock held): its
        edge (the last heartbeat's send tick + watchdog, moved on by the heartbeats queued before
        it) while the wire may still bring a heartbeat sent before it. None once one sent at or
        after it is queued (the host's own gap crossed the edge: the firmware cuts), once the
        allowance of wall time past the edge is spent (a dead host: cut, that much late), or
        unarmed."""
        to_host = self._to_host()
        if self.wire_allowance_s <= 0 or to_host is None:
            return None
        if not self._lib.vmcu_watchdog(ctypes.byref(self._wd_edge), ctypes.byref(self._wd_ticks)):
            return None
        edge, wd = int(self._wd_edge.value), int(self._wd_ticks.value)
        for when, _, _, heartbeat in self._rx_queue:
            if heartbeat:
                if when >= edge:
                    return None
                edge = when + wd
        if edge == self._released_edge:
            return None
        if time.monotonic() >= to_host(edge / self.clock_hz) + self.wire_allowance_s:
            self._released_edge = edge
            self.wire.cut_at_allowance += 1
            return None
        return edge

    def _defer_locked(self, upto: int) -> None:
        """Whether the watchdog's cut waits while the core runs to `upto` (lock held): while it
        is at or past the edge that the wire may still answer (_edge_locked). The core's time,
        its frames and the plant run on; only the cut waits. Counts the waits."""
        edge = self._edge_locked()
        waiting = edge is not None and upto >= edge
        if waiting == self._deferring:
            return
        if waiting:
            self._lib.vmcu_watchdog_defer(1)
            self._deferring, self._held_since = True, time.monotonic()
            self.wire.holds += 1
        else:  # moved on by a heartbeat sent in time; else crossed (the allowance spent: cut)
            self._end_deferral_locked(released=edge is not None)

    def _end_deferral_locked(self, released: bool) -> None:
        self._lib.vmcu_watchdog_defer(0)
        self._deferring = False
        self.wire.hold_max_ms = max(self.wire.hold_max_ms, (time.monotonic() - self._held_since) * 1e3)
        if released:
            self.wire.released_by_heartbeat += 1

    def _sent_times(self, data: bytes, arrival: float) -> list[tuple[float, bytes]]:
        """`data` cut after each heartbeat frame in it, each part with the time its last byte was
        on the wire at the latest: a heartbeat's own `host_us` (CLOCK_MONOTONIC µs when the host
        built it, mod 2**32), the rest `arrival`. Why: host bytes reach this pty through the
        kernel's tty flip-buffer work, a normal-priority kworker, which CPU hogs delay by tens of
        ms, so heartbeats the host wrote 12.5 ms apart were read, and went into the core, more
        than the 50 ms watchdog apart (firmware expiries while the host's own gaps stayed
        13-17 ms). A real UART or USB link puts the host's bytes on the wire when it writes
        them; so does this, for the frames that say when."""
        sync, size, hb_id = self._hb_head
        frame = FRAME_HEADER + size + FRAME_CRC
        buf = self._rx_tail + data
        skip = len(self._rx_tail)
        self._rx_tail = buf[-(frame - 1) :]
        parts: list[tuple[float, bytes]] = []
        start, last = 0, -math.inf
        arrival_us = int(arrival * 1e6)
        i = buf.find(sync)
        while 0 <= i <= len(buf) - frame:
            end = i + frame
            if buf[i + 1] == size and buf[i + 4] == hb_id and end > skip:
                body = buf[i : i + FRAME_HEADER + size]
                if zlib.crc32(body) == int.from_bytes(buf[i + FRAME_HEADER + size : end], "little"):
                    host_us = int.from_bytes(buf[i + FRAME_HEADER : i + FRAME_HEADER + size], "little")
                    age_us = (arrival_us - host_us) % 2**32
                    if age_us <= _HB_MAX_AGE_US:
                        self.wire.heartbeat(age_us * 1e-6)  # else not a time we can trust: the read's
                        sent = max(last, arrival - age_us * 1e-6)
                        parts.append((sent, data[start : end - skip]))
                        start, last = end - skip, sent
                    i = end - 1
            i = buf.find(sync, i + 1)
        if start < len(data):
            parts.append((arrival, data[start:]))
        return parts

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
