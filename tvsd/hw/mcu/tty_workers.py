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
`mcu.tty_workers` in the config picks one, or "off" ($TVSD_TTY_WORKERS overrides it, a
measuring knob). They serve other unbound work too (each item short). Needs CAP_SYS_NICE (what
--realtime needs); refused, it says so and the daemon runs on. What it changed is kept in a state
file beside the daemon's socket (tvsd.hw.mcu.tty_worker_state), so that a daemon killed with
SIGKILL is undone by the next one.
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from pathlib import Path

from tvsd.hw.mcu.tty_worker_state import PROC, Saved, StateFile, start_time

MODES = ("nice", "fifo", "off")
NICE = -20
FIFO_PRIORITY = 1  # the lowest real-time priority, below the daemon's (40-80) and the SIL's (30-46)
PERIOD_S = 1.0
ENV_MODE = "TVSD_TTY_WORKERS"  # a measuring knob, as TVSD_MLOCK: overrides mcu.tty_workers
UNBOUND_PREFIX = "kworker/u"

log = logging.getLogger(__name__)


def mode_from_env(default: str = "nice") -> str:
    """$TVSD_TTY_WORKERS if it names a mode, else `default` (the config's mcu.tty_workers)."""
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
    """The unbound kworkers raised (`mode` "nice" or "fifo") while running (see the module).

    `state_dir`: where what it changed is kept (tvsd.hw.mcu.tty_worker_state), so that a daemon
    killed before `stop()` is undone at the next start; None keeps it in memory only."""

    def __init__(
        self, mode: str = "nice", period_s: float = PERIOD_S, proc: Path = PROC, state_dir: Path | None = None
    ) -> None:
        if mode not in ("nice", "fifo"):
            raise ValueError(f"tty worker boost {mode!r}: nice or fifo")
        self.mode, self.period_s, self.proc = mode, period_s, proc
        # what it gives a worker: (policy, real-time priority, nice)
        self.given = (os.SCHED_OTHER, 0, NICE) if mode == "nice" else (os.SCHED_FIFO, FIFO_PRIORITY, 0)
        self.saved: dict[int, Saved] = {}  # the workers it changed, as they were
        self.state = StateFile(state_dir, self.given, proc) if state_dir is not None else None
        self.status = "not started"
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()  # apply (its thread) against stop (the event loop)

    @property
    def changed(self) -> set[int]:
        return set(self.saved)

    def _due(self, pid: int) -> bool:
        """Whether a worker is still at normal priority (the pool's new ones are)."""
        if os.sched_getscheduler(pid) != os.SCHED_OTHER:
            return False
        return self.mode == "fifo" or os.getpriority(os.PRIO_PROCESS, pid) > NICE

    def _give(self, pid: int) -> None:
        if self.mode == "fifo":
            os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(FIFO_PRIORITY))
        else:
            os.setpriority(os.PRIO_PROCESS, pid, NICE)

    def apply(self) -> int:
        """One pass: the workers still at normal priority raised; how many. Sets `status`.
        Each is recorded (state file) before it is changed: a kill in between leaves a record of
        a worker not raised, which `put_back` then leaves alone."""
        with self._lock:
            if self._stop.is_set():
                return 0
            due = []
            for pid in unbound_workers(self.proc):
                with contextlib.suppress(ProcessLookupError):  # the pool retired it meanwhile
                    if self._due(pid) and (saved := Saved.of(pid, self.proc)) is not None:
                        due.append(saved)
            # forget the retired (a pid the pool reuses is a new worker, recorded anew)
            self.saved = {p: s for p, s in self.saved.items() if start_time(p, self.proc) == s.start}
            raised = 0
            if due:
                self.saved.update({s.pid: s for s in due})
                self._write()
            for i, s in enumerate(due):
                try:
                    self._give(s.pid)
                except ProcessLookupError:
                    self.saved.pop(s.pid, None)
                    continue
                except PermissionError as exc:
                    for rest in due[i:]:  # those not reached (not those raised: review)
                        self.saved.pop(rest.pid, None)
                    self._write()
                    self.status = f"refused: {exc.strerror or exc} (needs CAP_SYS_NICE)"
                    return raised
                raised += 1
            how = f"nice {NICE}" if self.mode == "nice" else f"SCHED_FIFO {FIFO_PRIORITY}"
            found = len(unbound_workers(self.proc))
            # "granted" only with workers to raise: a kernel that names them otherwise (or a
            # container that shows none) must not read as a boost in force (review)
            self.status = (
                f"granted ({how}, {found} workers, {len(self.saved)} raised by this daemon)"
                if found
                else "none found: no unbound kworker (kworker/u*) threads to raise"
            )
            return raised

    def _write(self) -> None:
        if self.state is None:
            return
        try:
            if self.saved:
                self.state.write(self.saved)
            else:
                self.state.remove()
        except OSError as exc:  # a read-only or full runtime dir: the boost still works
            log.warning("tty workers: cannot keep %s (%s): a kill leaves them raised", self.state.path, exc)

    def _permitted(self) -> str | None:
        """None if this process may change the workers, else the refusal (asked even when every
        worker is raised already, by another daemon: this one could not keep them so)."""
        for pid in unbound_workers(self.proc):
            try:  # a change to what it has: a no-op, but checked for permission all the same
                os.sched_setscheduler(pid, os.sched_getscheduler(pid), os.sched_getparam(pid))
            except ProcessLookupError:
                continue
            except PermissionError as exc:
                return f"refused: {exc.strerror or exc} (needs CAP_SYS_NICE)"
            return None
        return None

    def start(self) -> str:
        """The first pass now (its status returned), then one every period_s on a thread."""
        refused = self._permitted()
        if refused is not None:
            self.status = refused
            return refused
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
        """Stop re-checking; the workers it raised back as they were (those still the same
        process with what it gave them), its state file removed (idempotent).
        Exclusive with a re-check pass: once `_stop` is set no pass begins (apply checks it under
        the lock), and one under way holds the lock, so it ends before anything is put back;
        no join's timeout is part of that (before the lock, a 2 s join that timed out let a pass
        raise a worker after the put-back, for good: tests/test_tty_worker_race.py)."""
        self._stop.set()
        with self._lock:
            kept = {}
            for pid, s in self.saved.items():
                try:
                    s.put_back(self.given, self.proc)
                except PermissionError:  # privileges dropped since: the next start tries
                    kept[pid] = s
            self.saved = kept
            self._write()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)  # at once: its next wait or pass sees _stop


# what a link without its tty workers raised risks, for the status (siltiming.md)
TTY_RISK = "under CPU load the MCU's bytes may wait behind other programs (faults mcu_stale, mcu_watchdog)"


def describe(mode: str | None, boost: TtyWorkerBoost | None) -> str:
    """The status line of a link's tty workers: `mode` None when nothing was requested (no
    --realtime), `boost` None when the mode is off. Refused or off under --realtime, it names what
    that risks (`tvsctl status` shows it)."""
    if mode is None:
        return "not requested"
    if boost is None:
        return f"off (mcu.tty_workers): {TTY_RISK}"
    status = boost.status
    return f"{status}: {TTY_RISK}" if status.startswith("refused") else status
