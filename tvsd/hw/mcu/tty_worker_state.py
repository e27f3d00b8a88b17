"""What the tty-worker boost changed, kept on disk so that a daemon that dies unannounced is undone.

A daemon killed with SIGKILL (or crashing) cannot put back the kernel's workers it raised
(tvsd.hw.mcu.tty_workers): after one test run every `kworker/u8:*` was still at nice -20 and
nobody knew which process had done it (docs/measurements/siltiming.md). So each boost writes what
it changed, before changing it, to `tty-workers-<pid>-<n>.json` in the daemon's runtime directory
(the socket's: /run/tvsd under systemd, kept across its restarts by RuntimeDirectoryPreserve=):
the boot's id, its own pid and start time, what it gives, and per worker its pid, start time and
original policy, real-time priority and nice. The next link to open or close (`restore_stale`)
puts back the workers of every file whose owner is gone, and removes the file; the owner removes
its own at close.

A pid alone is not a process: the kernel retires idle workers and reuses their pids. Each worker
and owner is therefore named by (pid, start time) (/proc/PID/stat field 22, clock ticks since
boot), and a worker is put back only if it is the same process and still has what the boost gave
it (another tool's later change is left alone).
"""

from __future__ import annotations

import contextlib
import itertools
import json
import logging
import os
from dataclasses import asdict, dataclass
from pathlib import Path

PROC = Path("/proc")
FILE_PREFIX = "tty-workers-"
NICE_POLICIES = (os.SCHED_OTHER, os.SCHED_BATCH, os.SCHED_IDLE)  # the ones nice applies to
_serial = itertools.count()  # two boosts in one process (tests) keep two files

log = logging.getLogger(__name__)


def boot_id(proc: Path = PROC) -> str:
    """This boot's id: a record from another boot names processes that no longer exist."""
    try:
        return (proc / "sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def start_time(pid: int, proc: Path = PROC) -> int | None:
    """The process's start time (clock ticks since boot), None if there is no such process."""
    try:
        text = (proc / str(pid) / "stat").read_text()
    except OSError:
        return None
    # fields after the command name, which may hold spaces and ')': the state is field 3
    rest = text[text.rindex(")") + 2 :].split()
    return int(rest[22 - 3])


@dataclass(frozen=True)
class Saved:
    """One worker as it was before the boost."""

    pid: int
    start: int  # start_time(): a recycled pid has another
    policy: int
    priority: int  # sched_param's (0 for the fair policies)
    nice: int

    @classmethod
    def of(cls, pid: int, proc: Path = PROC) -> Saved | None:
        """The worker's settings now; None if it is gone."""
        start = start_time(pid, proc)
        if start is None:
            return None
        policy, param = os.sched_getscheduler(pid), os.sched_getparam(pid)
        return cls(pid, start, policy, param.sched_priority, os.getpriority(os.PRIO_PROCESS, pid))

    def put_back(self, given: tuple[int, int, int], proc: Path = PROC) -> bool:
        """Restore the worker if it is the same process and still has `given` (policy, priority,
        nice: what the boost set); whether it was restored. PermissionError passes up."""
        if start_time(self.pid, proc) != self.start:
            return False  # retired, or its pid is another process's now
        try:
            policy, prio = os.sched_getscheduler(self.pid), os.sched_getparam(self.pid).sched_priority
            now = (policy, prio, os.getpriority(os.PRIO_PROCESS, self.pid) if policy in NICE_POLICIES else 0)
            if now != given:
                return False  # someone changed it since: theirs now
            os.sched_setscheduler(self.pid, self.policy, os.sched_param(self.priority))
            if self.policy in NICE_POLICIES:
                os.setpriority(os.PRIO_PROCESS, self.pid, self.nice)
        except ProcessLookupError:
            return False
        return True


class StateFile:
    """One boost's record in `directory` (written whole, by rename: a kill leaves the old or the new)."""

    def __init__(self, directory: Path, given: tuple[int, int, int], proc: Path = PROC) -> None:
        self.path = directory / f"{FILE_PREFIX}{os.getpid()}-{next(_serial)}.json"
        self.given, self.proc = given, proc

    def write(self, saved: dict[int, Saved]) -> None:
        body = {
            "boot": boot_id(self.proc),
            "owner": os.getpid(),
            "owner_start": start_time(os.getpid(), self.proc),
            "given": list(self.given),
            "workers": [asdict(s) for s in saved.values()],
        }
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(body), encoding="utf-8")
        os.replace(tmp, self.path)

    def remove(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def restore_stale(directory: Path, proc: Path = PROC) -> list[str]:
    """Put back the workers recorded by boosts whose process is gone; one line per file handled
    (for the log). A file whose owner lives is left; one that cannot be read is removed; one whose
    workers could not be put back (no CAP_SYS_NICE) is kept for a daemon that can."""
    done = []
    for path in sorted(directory.glob(f"{FILE_PREFIX}*.json")):
        try:
            body = json.loads(path.read_text(encoding="utf-8"))
            owner, owner_start = int(body["owner"]), body["owner_start"]
            given = tuple(int(v) for v in body["given"])
            workers = [Saved(**w) for w in body["workers"]]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            done.append(f"{path.name}: unreadable ({exc}), removed")
            with contextlib.suppress(OSError):
                path.unlink()
            continue
        if body.get("boot") != boot_id(proc):  # (early kthreads' pids and start times repeat)
            done.append(f"{path.name}: from another boot, removed")
            with contextlib.suppress(OSError):
                path.unlink()
            continue
        if owner_start is not None and start_time(owner, proc) == owner_start:
            continue  # its daemon runs: it puts them back itself
        try:
            back = sum(w.put_back(given, proc) for w in workers)  # type: ignore[arg-type]
        except PermissionError as exc:
            done.append(f"{path.name}: cannot put back its workers ({exc.strerror}); kept")
            continue
        done.append(f"{path.name} (pid {owner}, gone): {back} of {len(workers)} workers put back")
        with contextlib.suppress(OSError):
            path.unlink()
    for line in done:
        log.warning("tty workers left raised by an earlier daemon: %s", line)
    return done
