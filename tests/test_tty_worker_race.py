"""The tty-worker boost's stop against its once-a-second re-check (tvsd.hw.mcu.tty_workers; review).

The re-check runs on its own thread; `stop()` (the link's close, on the event loop) puts back what
the boost raised. Had a re-check pass been under way while stop put the workers back, it could
raise a worker after stop had restored it, and nothing would ever put that one back: the
first boost (fc16a15) stopped its thread with a 2 s join and restored whether or not the join
had ended. Here the interleaving is forced, not hoped for: the pass is held inside its scan of
/proc (a fake /proc whose one "kworker" is a child process of the test, so no real kernel worker
is touched) until stop is waiting for it, or has returned; then it is let go.

Needs CAP_SYS_NICE (raising a process to nice -20): skipped without.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tvsd.hw.mcu.tty_workers import NICE, TtyWorkerBoost

THREAD = "tvsd-tty-workers"  # the re-check thread's name
WAIT_S = 30.0  # a guard only: every wait below ends on an event the code under test sets


def _may_renice() -> bool:
    try:
        os.setpriority(os.PRIO_PROCESS, os.getpid(), os.getpriority(os.PRIO_PROCESS, os.getpid()) - 1)
    except OSError:
        return False
    os.setpriority(os.PRIO_PROCESS, os.getpid(), os.getpriority(os.PRIO_PROCESS, os.getpid()) + 1)
    return True


pytestmark = pytest.mark.skipif(not _may_renice(), reason="needs CAP_SYS_NICE")


@pytest.fixture
def workers(tmp_path: Path) -> Iterator[tuple[Path, list[int]]]:
    """A /proc of three "kworkers": child processes (their comm and stat as the boost
    reads them; the stat copied, its start time field does not change)."""
    kids = [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"]) for _ in range(3)]
    try:
        for n, kid in enumerate(kids):
            d = tmp_path / str(kid.pid)
            d.mkdir()
            (d / "comm").write_text(f"kworker/u99:{n}\n")
            (d / "stat").write_text(Path(f"/proc/{kid.pid}/stat").read_text())
        yield tmp_path, [k.pid for k in kids]
    finally:
        for kid in kids:
            kid.kill()
            kid.wait()


def _nice(pid: int) -> int:
    return os.getpriority(os.PRIO_PROCESS, pid)


class _Gate:
    """Holds the re-check thread's first pass inside its scan of /proc until let go."""

    def __init__(self) -> None:
        self.entered, self.go, self.armed = threading.Event(), threading.Event(), True

    def proc(self, root: Path) -> Path:
        gate = self

        class GatedProc(type(root)):  # type: ignore[misc,valid-type]
            def iterdir(self) -> Any:
                if gate.armed and threading.current_thread().name == THREAD:
                    gate.armed = False
                    gate.entered.set()
                    assert gate.go.wait(WAIT_S)
                return super().iterdir()

        return GatedProc(root)


class _WatchedLock:
    """The boost's lock, saying when the stopping thread asks for it (before it has it)."""

    def __init__(self, asked: threading.Event) -> None:
        self._lock, self._asked = threading.Lock(), asked

    def __enter__(self) -> bool:
        if threading.current_thread().name == "stopper":
            self._asked.set()
        return self._lock.__enter__()

    def __exit__(self, *exc: object) -> None:
        self._lock.__exit__(*exc)


def test_a_recheck_under_way_when_stop_comes_raises_nothing_that_stays_raised(
    workers: tuple[Path, list[int]],
) -> None:
    root, pids = workers
    gate = _Gate()
    boost = TtyWorkerBoost("nice", period_s=0.001, proc=gate.proc(root))
    stop_waits = threading.Event()  # stop asked for the lock, or returned
    boost._lock = _WatchedLock(stop_waits)  # type: ignore[assignment]
    assert boost.start().startswith("granted"), boost.status  # the first pass, on this thread
    assert all(_nice(p) == NICE for p in pids)
    assert gate.entered.wait(WAIT_S)  # the re-check's pass has begun, and is held
    for p in pids:  # meanwhile the workers are at normal priority again (as new pool workers are)
        os.setpriority(os.PRIO_PROCESS, p, 0)

    def stop() -> None:
        boost.stop()
        stop_waits.set()

    stopper = threading.Thread(target=stop, name="stopper")
    stopper.start()
    assert stop_waits.wait(WAIT_S)  # stop is waiting for the pass (or, unguarded, has restored)
    gate.go.set()  # the pass goes on: it raises what it finds at normal priority
    stopper.join(WAIT_S)
    assert not stopper.is_alive()
    assert boost._thread is not None
    boost._thread.join(WAIT_S)
    assert not boost._thread.is_alive()
    assert [_nice(p) for p in pids] == [0, 0, 0]  # stop came last: nothing left raised
    assert not boost.changed


def test_a_refusal_midway_keeps_the_record_of_a_worker_raised_before_it(
    workers: tuple[Path, list[int]], tmp_path: Path
) -> None:
    """A pass in which one worker vanished, the next was raised and the third refused: the raised
    one must stay on record (else no stop or later daemon ever puts it back). Before, the
    refusal dropped the records from the refused worker's position counted in raised workers
    (one too early after a vanished one): the raised worker was forgotten and left at -20."""
    root, pids = workers
    before = [_nice(p) for p in pids]  # (the test's own nice: 19 under `nice -n 19 pytest`)
    given: list[int] = []

    class Flaky(TtyWorkerBoost):
        def _give(self, pid: int) -> None:
            if len(given) == 0:
                given.append(-pid)
                raise ProcessLookupError(pid)
            if len(given) == 2:
                raise PermissionError(1, "Operation not permitted")
            given.append(pid)
            super()._give(pid)

    boost = Flaky("nice", period_s=100.0, proc=root, state_dir=tmp_path / "run")
    (tmp_path / "run").mkdir()
    boost.apply()
    raised = [p for p in given if p > 0]
    assert len(raised) == 1 and _nice(raised[0]) == NICE
    assert boost.status.startswith("refused"), boost.status
    assert boost.changed == set(raised)
    boost.stop()
    assert [_nice(p) for p in pids] == before
