"""The kernel's tty flip-buffer workers, kept ahead of normal-priority load (--realtime).

Every byte a serial port receives (a real UART's or USB adapter's, and both sides of the SIL's
pty) reaches the reader through the tty layer's `flush_to_ldisc` work, run by a kworker of the
kernel's unbound workqueue (`kworker/uN:M`) at normal priority. Traced in the soak
(docs/measurements/siltiming.md): a kworker preempted in the middle of that work by the daemon's
real-time threads stayed runnable but unscheduled for 0.2-0.72 s while normal-priority tasks (the
CPU hogs, other jobs) ran; the port's next work waits behind it (a work item does not run twice
at once), so the MCU's state frames reached the daemon up to 719 ms late (its late-input hold
latches at 500 ms: `mcu_stale`), and in the SIL the host's heartbeats reached the virtual
firmware as late (its watchdog cut: `mcu_watchdog`), while the daemon's and the SIL's own
threads were on time.

`TtyWorkerBoost` puts those kworkers on SCHED_FIFO `priority` (1: below every tvsd thread, above
all normal-priority tasks) and re-checks every PERIOD_S (the pool creates workers on demand; a new
one starts at normal priority). At `stop()` it puts the ones it changed back to SCHED_OTHER. They
serve other unbound work too: each item is short, and the kernel's RT throttling
(sched_rt_runtime_us) still leaves normal tasks their share. Needs CAP_SYS_NICE (what --realtime
needs); refused, it says so and the daemon runs on without it.
"""

from __future__ import annotations

import contextlib
import os
import threading
from pathlib import Path

PRIORITY = 1  # SCHED_FIFO: the lowest real-time priority, below the daemon's (40-80) and the SIL's (30-46)
PERIOD_S = 1.0
ENV_PRIORITY = "TVSD_TTY_WORKER_PRIORITY"  # a measuring knob: another priority; 0 turns the boost off
UNBOUND_PREFIX = "kworker/u"
PROC = Path("/proc")


def priority_from_env(default: int = PRIORITY) -> int:
    """$TVSD_TTY_WORKER_PRIORITY if it is an integer in 0..99 (0: off), else `default`."""
    raw = os.environ.get(ENV_PRIORITY, "").strip()
    return int(raw) if raw.isdigit() and 0 <= int(raw) <= 99 else default


def unbound_workers(proc: Path = PROC) -> list[int]:
    """The pids of the unbound workqueue's kworkers now (kernel threads named kworker/uN:M)."""
    out = []
    for d in proc.iterdir():
        if not d.name.isdigit():
            continue
        with contextlib.suppress(OSError):
            if (d / "comm").read_text().startswith(UNBOUND_PREFIX):
                out.append(int(d.name))
    return out


class TtyWorkerBoost:
    """SCHED_FIFO `priority` for the unbound kworkers while running (see the module's text)."""

    def __init__(self, priority: int = PRIORITY, period_s: float = PERIOD_S, proc: Path = PROC) -> None:
        self.priority, self.period_s, self.proc = priority, period_s, proc
        self.changed: set[int] = set()
        self.status = "not started"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def apply(self) -> int:
        """One pass: the kworkers still at normal priority raised; how many. Sets `status`."""
        raised = 0
        for pid in unbound_workers(self.proc):
            try:
                if os.sched_getscheduler(pid) != os.SCHED_OTHER:
                    continue
                os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(self.priority))
            except ProcessLookupError:  # the pool retired it meanwhile
                continue
            except PermissionError as exc:
                self.status = f"refused: {exc.strerror or exc} (needs CAP_SYS_NICE)"
                return raised
            self.changed.add(pid)
            raised += 1
        self.status = f"granted (SCHED_FIFO {self.priority}, {len(self.changed)} workers)"
        return raised

    def start(self) -> str:
        """The first pass now (its status returned), then one every period_s on a thread."""
        self.apply()
        if self.status.startswith("refused"):
            return self.status
        self._thread = threading.Thread(target=self._run, name="tvsd-tty-workers", daemon=True)
        self._thread.start()
        return self.status

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.apply()

    def stop(self) -> None:
        """Stop re-checking; the kworkers it raised back to SCHED_OTHER (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for pid in self.changed:
            with contextlib.suppress(OSError):
                if os.sched_getscheduler(pid) == os.SCHED_FIFO:
                    os.sched_setscheduler(pid, os.SCHED_OTHER, os.sched_param(0))
        self.changed.clear()
