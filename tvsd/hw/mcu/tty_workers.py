"""The kernel's tty flip-buffer workers, kept ahead of normal-priority load (--realtime).

Every byte a serial port receives (a real UART's or USB adapter's, and both sides of the SIL's
pty) reaches the reader through the tty layer's `flush_to_ldisc` work, run by a kworker of the
kernel's unbound workqueue (`kworker/uN:M`) at normal priority. Traced in the soak
(docs/measurements/siltiming.md): a kworker preempted in the middle of that work by the daemon's
real-time threads stayed runnable but unscheduled for 0.2-0.72 s while normal-priority tasks (the
CPU hogs, other jobs) ran; the port's next work waits behind it (a work item does not run twice
at once), so the MCU's state frames reached the daemon up to 1.2 s late (the late-input hold
latches at 500 ms: `mcu_stale`), and in the SIL the host's heartbeats reached the virtual
firmware as late (its watchdog cut: `mcu_watchdog`), while the daemon's and the SIL's own
threads were on time.

`TtyWorkerBoost` raises those kworkers and re-checks every PERIOD_S (the pool creates workers on
demand, at normal priority); at `stop()` it puts back the ones it changed. Two ways (MODES):
- "nice" (the default): SCHED_OTHER at nice NICE. The fair scheduler then runs a woken worker
  almost at once (weight 88761 against a hog's 1024), and its time stays out of the real-time
  budget (sched_rt_runtime_us), so it can take no real-time time from the control loop;
- "fifo": SCHED_FIFO FIFO_PRIORITY (1, below every tvsd thread); its time counts as real-time.
Both took the pty's worst delay in the soak from 255-994 ms to 4-75 ms (no cut at the wire
model's allowance, no mcu_stale).
$TVSD_TTY_WORKERS picks one, or "off". They serve other unbound work too (each item short).
Needs CAP_SYS_NICE (what --realtime needs); refused, it says so and the daemon runs on.
"""

from __future__ import annotations

import contextlib
import os
import threading
from pathlib import Path

MODES = ("nice", "fifo", "off")
NICE = -20
FIFO_PRIORITY = 1  # the lowest real-time priority, below the daemon's (40-80) and the SIL's (30-46)
PERIOD_S = 1.0
ENV_MODE = "TVSD_TTY_WORKERS"  # a measuring knob, as TVSD_MLOCK: nice (default), fifo or off
UNBOUND_PREFIX = "kworker/u"
PROC = Path("/proc")


def mode_from_env(default: str = "nice") -> str:
    """$TVSD_TTY_WORKERS if it names a mode, else `default`."""
    raw = os.environ.get(ENV_MODE, "").strip()
    return raw if raw in MODES else default


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
    """The unbound kworkers raised (`mode` "nice" or "fifo") while running (see the module)."""

    def __init__(self, mode: str = "nice", period_s: float = PERIOD_S, proc: Path = PROC) -> None:
        if mode not in ("nice", "fifo"):
            raise ValueError(f"tty worker boost {mode!r}: nice or fifo")
        self.mode, self.period_s, self.proc = mode, period_s, proc
        self.changed: set[int] = set()
        self.status = "not started"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _raise(self, pid: int) -> bool:
        """Raise one worker if it is still at normal priority; whether it was changed."""
        if os.sched_getscheduler(pid) != os.SCHED_OTHER:
            return False
        if self.mode == "fifo":
            os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
            return True
        if os.getpriority(os.PRIO_PROCESS, pid) <= NICE:
            return False
        os.setpriority(os.PRIO_PROCESS, pid, NICE)
        return True

    def apply(self) -> int:
        """One pass: the workers still at normal priority raised; how many. Sets `status`."""
        raised = 0
        for pid in unbound_workers(self.proc):
            try:
                if not self._raise(pid):
                    continue
            except ProcessLookupError:  # the pool retired it meanwhile
                continue
            except PermissionError as exc:
                self.status = f"refused: {exc.strerror or exc} (needs CAP_SYS_NICE)"
                return raised
            self.changed.add(pid)
            raised += 1
        how = f"nice {NICE}" if self.mode == "nice" else f"SCHED_FIFO {FIFO_PRIORITY}"
        self.status = f"granted ({how}, {len(self.changed)} workers)"
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
        """Stop re-checking; the workers it raised back to SCHED_OTHER, nice 0 (idempotent)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for pid in self.changed:
            with contextlib.suppress(OSError):
                if self.mode == "fifo" and os.sched_getscheduler(pid) == os.SCHED_FIFO:
                    os.sched_setscheduler(pid, os.SCHED_OTHER, os.sched_param(0))
                elif self.mode == "nice" and os.getpriority(os.PRIO_PROCESS, pid) == NICE:
                    os.setpriority(os.PRIO_PROCESS, pid, 0)
        self.changed.clear()
