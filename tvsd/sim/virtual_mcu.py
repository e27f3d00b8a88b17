"""Virtual MCU: the real firmware core, built for the host, behind a real pseudo-terminal.

The same C core that runs on the ATmega328P (``firmware/core``), compiled with a host board
layer into a shared library and loaded with ctypes. Who owns what:

- this module: the transport, a pty with the pump thread that moves bytes between it and the
  core (and the wall clock's advance), the cable-cut fault, the pty's lifetime;
- :mod:`tvsd.sim.vmcu_core` (:class:`McuCore`, the base of :class:`VirtualMcu`): the core's
  clock, its UART queues, the plant's inputs and outputs;
- :mod:`tvsd.sim.vmcu_library`: finding, building (tests, developers) and loading the library;
- :mod:`tvsd.sim.mcu_wire`: the wire model (heartbeats' send times, the watchdog cut held at its
  edge for the pty's late hand-over), called by the core under its lock.

The names callers and tests use (:class:`VirtualMcu`, :class:`VirtualMcuError`, ``PULSE_*``, the
library's functions) are all importable from here.

Anything that opens :attr:`VirtualMcu.port` with pyserial talks to the firmware's own parser,
command table, watchdog and stepper planner, byte for byte. A paced plant writes the core's
output itself after each step (:meth:`VirtualMcu.write_out`): the pump's select() waits for the
kernel's tty flip-buffer worker, which CPU load delays.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import threading
import time
import tty
from pathlib import Path
from types import TracebackType
from typing import Literal

from tvsd.sim.vmcu_core import PULSE_OPTICAL, PULSE_ZERO, STEPPER_AXES, McuCore
from tvsd.sim.vmcu_library import (
    FIRMWARE_DIR,
    LIBRARY,
    PACKAGED_MODULE,
    VirtualMcuError,
    build_library,
    default_library,
    packaged_library,
)

# The core's and the library's names stay importable from here, where callers and tests have
# always found them.
__all__ = [
    "FIRMWARE_DIR",
    "LIBRARY",
    "PACKAGED_MODULE",
    "PULSE_OPTICAL",
    "PULSE_ZERO",
    "STEPPER_AXES",
    "McuCore",
    "VirtualMcu",
    "VirtualMcuError",
    "build_library",
    "default_library",
    "packaged_library",
]

_PUMP_PERIOD_S = 0.001


class VirtualMcu(McuCore):
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
        """The core (:class:`McuCore`: its arguments), then its pty and the pump thread."""
        super().__init__(
            counts_per_rev=counts_per_rev,
            drive_volts=drive_volts,
            clock=clock,
            library=library,
            wire_allowance_s=wire_allowance_s,
        )
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # bytes pass untouched: no echo, no line discipline
        os.set_blocking(self._master, False)
        self.port: str = os.ttyname(self._slave)
        self._stop = threading.Event()
        self._closed = False
        self.cable_cut = False  # fault injection: both directions lost, the core runs on
        self._thread = threading.Thread(target=self._pump, name="virtual-mcu", daemon=True)
        self._thread.start()

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
                if data:
                    self._receive_locked(data, arrival, timeline, at)
                if not self._write_locked():
                    return

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
        self._release()

    def __enter__(self) -> VirtualMcu:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
