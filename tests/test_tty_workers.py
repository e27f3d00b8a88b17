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
import os
import subprocess
import sys
import tty
from collections.abc import Iterator

import pytest
import test_late_input as late
import test_virtual_mcu_wire as wire
from test_virtual_mcu_wire import rig  # noqa: F401 (the fixture, by name)

from tvsd.control.runner import Runner
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
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
