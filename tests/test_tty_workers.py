"""The kernel's tty workers kept ahead of normal-priority load (tvsd.hw.mcu.tty_workers; issue 13).

Every byte a tty receives reaches its reader through `flush_to_ldisc`, run by a kworker of the
unbound workqueue at normal priority; traced in the soak, such a kworker preempted mid-work by the
daemon's real-time threads stood runnable 0.2-0.72 s while CPU hogs ran, and held the MCU's
frames (and, in the SIL, the host's heartbeats) that long (docs/measurements/siltiming.md). With
--realtime the MCU link raises those kworkers (nice -20) while it is open.

Checked here: the boost raises them and puts them back; the link does it under --realtime only;
a user without CAP_SYS_NICE gets a plain refusal, not an error; and with the workers raised both
safety properties still hold, by the same tests as without (a host that stops is cut by the
virtual firmware within its watchdog + G; an MCU that stops latches STALE on the host).
Needs CAP_SYS_NICE (skipped without: the workers' priorities are the machine's).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import tty
from collections.abc import Iterator
from dataclasses import asdict, replace
from pathlib import Path

import pytest
import test_late_input as late
import test_virtual_mcu_wire as wire
from test_virtual_mcu_wire import rig  # noqa: F401 (the fixture, by name)

from tvsd.control.runner import Runner
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
from tvsd.hw.mcu.tty_worker_state import FILE_PREFIX, Saved, boot_id, restore_stale, start_time
from tvsd.hw.mcu.tty_workers import NICE, TtyWorkerBoost, unbound_workers


def _may_raise_kworkers() -> bool:
    try:
        pids = unbound_workers()
        if not pids:
            return False
        pid = pids[0]
        policy, param = os.sched_getscheduler(pid), os.sched_getparam(pid)
        os.sched_setscheduler(pid, policy, param)  # a no-op change: is it permitted?
    except OSError:
        return False
    return True


pytestmark = pytest.mark.skipif(
    not _may_raise_kworkers(), reason="needs CAP_SYS_NICE over the kernel's kworkers"
)


def _classes() -> dict[int, tuple[int, int]]:
    """Each unbound kworker's (policy, nice)."""
    out = {}
    for pid in unbound_workers():
        try:
            out[pid] = (os.sched_getscheduler(pid), os.getpriority(os.PRIO_PROCESS, pid))
        except OSError:
            continue
    return out


@pytest.fixture
def boost() -> Iterator[TtyWorkerBoost]:
    b = TtyWorkerBoost(period_s=0.1)
    assert b.start().startswith("granted"), b.status
    try:
        yield b
    finally:
        b.stop()


@pytest.mark.parametrize("mode", ["nice", "fifo"])
def test_the_boost_raises_every_unbound_worker_and_puts_back_those_it_raised(mode: str) -> None:
    before = _classes()
    b = TtyWorkerBoost(mode, period_s=0.1)
    try:
        assert b.start().startswith("granted"), b.status
        now = _classes()
        if mode == "nice":  # still fair-scheduled (no real-time budget), at nice -20
            assert all(pol == os.SCHED_OTHER and nice <= NICE for pol, nice in now.values()), now
        else:
            assert all(pol == os.SCHED_FIFO for pol, _ in now.values()), now
        assert b.changed <= set(before)
    finally:
        changed = set(b.changed)
        b.stop()
    back = _classes()
    assert all(back[pid] == before[pid] for pid in changed if pid in back), (before, back)
    assert not b.changed


def test_the_links_realtime_raises_the_tty_workers_and_only_it() -> None:
    """McuLink with an I/O priority (tvsd --realtime) raises them while open; without, leaves them."""
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)

    async def open_close(io_priority: int | None) -> tuple[str, dict[int, tuple[int, int]], set[int]]:
        link = McuLink(McuSettings(port=port), load_spec(), io_priority=io_priority)
        await link.open()
        try:
            raised = set(link._tty_workers.changed) if link._tty_workers is not None else set()
            return link.tty_workers, _classes(), raised
        finally:
            await link.close()

    try:
        before = _classes()
        status, during, raised = asyncio.run(open_close(60))
        assert status.startswith(f"granted (nice {NICE}"), status
        assert all(nice <= NICE for _, nice in during.values()), during
        after = _classes()
        assert all(after[pid] == before[pid] for pid in raised if pid in after), after  # put back
        status, _, raised = asyncio.run(open_close(None))
        assert status == "not requested" and not raised
    finally:
        os.close(slave)
        os.close(master)


def test_without_the_capability_the_boost_says_refused_and_changes_nothing() -> None:
    """As a user without CAP_SYS_NICE (uid nobody, in a child): one plain status, no exception."""
    code = (
        "import os\n"
        "from tvsd.hw.mcu.tty_workers import TtyWorkerBoost\n"
        "os.setresuid(65534, 65534, 65534)\n"  # root's capabilities go with uid 0
        "b = TtyWorkerBoost()\nprint(b.start())\nb.stop()\n"
    )
    before = _classes()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "refused: Operation not permitted (needs CAP_SYS_NICE)", out.stdout
    after = _classes()
    assert all(after[pid] == cls for pid, cls in before.items() if pid in after)


def test_with_the_workers_raised_a_host_that_stops_is_still_cut(boost: TtyWorkerBoost, rig: wire.Rig) -> None:  # noqa: F811
    """The virtual firmware's watchdog property, unchanged by the boost (the same test)."""
    wire.test_a_host_that_stops_is_cut_within_watchdog_plus_allowance_and_stays_cut(rig)


def test_with_the_workers_raised_an_mcu_that_stops_latches_stale(
    boost: TtyWorkerBoost, runner: Runner
) -> None:
    """The host's stale property, unchanged by the boost (the same test)."""
    late.test_silence_beyond_the_bound_latches_stale_and_the_link_is_lost(runner)


# --- a daemon killed with the workers raised (tvsd.hw.mcu.tty_worker_state) -----------------------

_KILLED_BOOST = (
    "import sys, time\n"
    "from pathlib import Path\n"
    "from tvsd.hw.mcu.tty_workers import TtyWorkerBoost\n"
    "b = TtyWorkerBoost(period_s=0.1, state_dir=Path(sys.argv[1]))\n"
    "print(b.start(), flush=True)\n"
    "time.sleep(120)\n"  # killed long before
)


def _one_at_normal_priority() -> None:
    """At least one worker at nice 0, as the pool makes them: if every one is raised already
    (another daemon's boost, or one killed before this fix), one is put back first (a live boost
    raises it again within its period)."""
    classes = _classes()
    if any(cls == (os.SCHED_OTHER, 0) for cls in classes.values()):
        return
    for pid, (policy, _) in classes.items():
        if policy == os.SCHED_OTHER:
            with contextlib.suppress(ProcessLookupError):
                os.setpriority(os.PRIO_PROCESS, pid, 0)
                return
    pytest.skip("no unbound worker is fair-scheduled: another boost runs them SCHED_FIFO")


def _killed_boost(state_dir: Path) -> dict[str, object]:
    """A child that raises the workers, SIGKILLed while they are raised: its state file."""
    _one_at_normal_priority()
    child = subprocess.Popen(
        [sys.executable, "-c", _KILLED_BOOST, str(state_dir)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout is not None
        status = child.stdout.readline()
        assert status.startswith("granted"), status
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait(10)
    files = list(state_dir.glob(f"{FILE_PREFIX}*.json"))
    assert len(files) == 1, files  # it raised at least the one at normal priority
    body: dict[str, object] = json.loads(files[0].read_text())
    assert body["workers"], body
    return body


def test_a_boost_killed_with_sigkill_is_undone_by_the_next_links_open(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """The state file outlives the killed boost, its workers stay raised; the next McuLink that
    opens with that state dir (no boost of its own: no --realtime) puts every one back as it was
    and removes the file. Before: no file, and the workers stayed at nice -20 until the kernel
    retired them. (Another boost on this shared machine, e.g. a --realtime daemon, raises them
    again within its 1 s period: the classes are compared right after the open, and the count
    put back is from the restore's own line.)"""
    body = _killed_boost(tmp_path)
    before = {w["pid"]: (w["policy"], w["nice"]) for w in body["workers"]}  # type: ignore[attr-defined]
    recorded = {w["pid"]: w for w in body["workers"]}  # type: ignore[attr-defined]
    still = _classes()
    assert all(still[p][1] == NICE for p in recorded if p in still), still  # left raised by the kill
    master, slave = os.openpty()
    tty.setraw(slave)

    async def open_close() -> None:
        link = McuLink(McuSettings(port=os.ttyname(slave)), load_spec(), state_dir=tmp_path)
        await link.open()
        await link.close()

    try:
        with caplog.at_level(logging.WARNING, logger="tvsd.hw.mcu"):
            asyncio.run(open_close())
    finally:
        os.close(slave)
        os.close(master)
    after = _classes()
    alive = [p for p in recorded if start_time(p) == recorded[p]["start"]]
    said = [r.getMessage() for r in caplog.records if "put back" in r.getMessage()]
    assert len(said) == 1 and f": {len(alive)} of {len(recorded)} workers put back" in said[0], said
    assert any(after.get(p) == before[p] for p in alive), (before, after)
    assert not list(tmp_path.glob(f"{FILE_PREFIX}*")), "the file is removed once undone"


def _record(folder: Path, owner: int, owner_start: int | None, saved: Saved, boot: str) -> str:
    """A record as a boost writes it (tvsd.hw.mcu.tty_worker_state.StateFile); its file name."""
    name = f"{FILE_PREFIX}{owner}-0.json"
    body = {"boot": boot, "owner": owner, "owner_start": owner_start, "given": [os.SCHED_OTHER, 0, NICE]}
    (folder / name).write_text(json.dumps({**body, "workers": [asdict(saved)]}))
    return name


def test_a_recycled_worker_pid_is_not_touched(tmp_path: Path) -> None:
    """A record whose pid now names another process (another start time: the pool retired the
    worker and the pid was reused) leaves that process alone, and so does a record from another
    boot or one whose owner lives; with the right start time and a dead owner it is put back. The
    'worker' is a child process at nice -20 (as the boost leaves one)."""
    victim = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        pid = victim.pid
        os.setpriority(os.PRIO_PROCESS, pid, NICE)  # as if the boost had raised it
        real = start_time(pid)
        assert real is not None
        code = "import os; print(os.getpid())"
        gone = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        owner = int(gone.stdout)  # a process that has ended: the owner was killed
        boot = boot_id()
        was = Saved(pid, real, os.SCHED_OTHER, 0, 0)

        name = _record(tmp_path, owner, 1, replace(was, start=real - 1), boot)  # pid recycled since
        assert restore_stale(tmp_path) == [f"{name} (pid {owner}, gone): 0 of 1 workers put back"]
        assert os.getpriority(os.PRIO_PROCESS, pid) == NICE  # untouched
        assert not list(tmp_path.glob(f"{FILE_PREFIX}*"))  # the dead owner's file goes

        name = _record(tmp_path, owner, 1, was, "another-boot")
        assert restore_stale(tmp_path) == [f"{name}: from another boot, removed"]
        assert os.getpriority(os.PRIO_PROCESS, pid) == NICE

        _record(tmp_path, os.getpid(), start_time(os.getpid()), was, boot)  # its owner lives
        assert restore_stale(tmp_path) == []
        assert os.getpriority(os.PRIO_PROCESS, pid) == NICE
        (tmp_path / f"{FILE_PREFIX}{os.getpid()}-0.json").unlink()

        name = _record(tmp_path, owner, 1, was, boot)  # the same process, its owner gone
        assert restore_stale(tmp_path) == [f"{name} (pid {owner}, gone): 1 of 1 workers put back"]
        assert os.getpriority(os.PRIO_PROCESS, pid) == 0  # the check above was the start time
    finally:
        victim.kill()
        victim.wait()


def test_a_live_boost_keeps_its_record_and_removes_it_at_stop(tmp_path: Path) -> None:
    """While running the file lists what was changed, with each worker's original settings; at
    stop the workers are back and the file is gone."""
    before = _classes()
    b = TtyWorkerBoost(period_s=0.1, state_dir=tmp_path)
    try:
        assert b.start().startswith("granted"), b.status
        assert b.state is not None
        if b.changed:
            body = json.loads(b.state.path.read_text())
            assert {w["pid"] for w in body["workers"]} == b.changed
            was = [((w["policy"], w["nice"]), before.get(w["pid"])) for w in body["workers"]]
            assert all(b is None or a == b for a, b in was), was
    finally:
        b.stop()
    assert not list(tmp_path.glob(f"{FILE_PREFIX}*"))
