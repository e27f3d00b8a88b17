"""What the status says of the kernel's tty workers (link.tty_workers; branch ttyrestore).

Under --realtime the MCU link raises the kworkers that hand it the MCU's bytes
(tvsd.hw.mcu.tty_workers). When that is refused (no CAP_SYS_NICE) or turned off (mcu.tty_workers:
off), the link may fault under CPU load (docs/measurements/siltiming.md): the status then says so,
on the one line `tvsctl status` prints for the key, with the risk named. Without --realtime
nothing was asked: "not requested", nothing more (the daemon's start-up warning covers that case).
"""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import tty
from dataclasses import replace
from pathlib import Path

import pytest

from tvsd.cli.daemon_cmds import show
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec
from tvsd.hw.mcu.tty_workers import TTY_RISK, TtyWorkerBoost


def _status_of(settings: McuSettings, io_priority: int | None) -> str:
    """link.tty_workers of a link opened (and closed) on a pty with these settings."""
    master, slave = os.openpty()
    tty.setraw(slave)

    async def open_close() -> str:
        link = McuLink(replace(settings, port=os.ttyname(slave)), load_spec(), io_priority=io_priority)
        await link.open()
        try:
            return link.tty_workers
        finally:
            await link.close()

    try:
        return asyncio.run(open_close())
    finally:
        os.close(slave)
        os.close(master)


def test_off_under_realtime_names_the_key_and_the_risk(capsys: pytest.CaptureFixture[str]) -> None:
    """mcu.tty_workers: off with --realtime: one line in `tvsctl status` with the key and the risk
    (before: "not requested", as without --realtime: nothing told the user why the link faults)."""
    status = _status_of(McuSettings(tty_workers="off"), io_priority=60)
    assert status == f"off (mcu.tty_workers): {TTY_RISK}"
    show({"state": "idle", "link": {"state": "ok", "tty_workers": status}}, as_json=False)
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "tty_workers" in ln]
    assert len(lines) == 1 and "mcu_stale" in lines[0] and len(lines[0]) < 160, lines


def test_without_realtime_it_is_not_requested() -> None:
    assert _status_of(McuSettings(), io_priority=None) == "not requested"


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to become an unprivileged user in a child")
def test_refused_names_the_capability_and_the_risk(tmp_path: object) -> None:
    """As a user without CAP_SYS_NICE (uid nobody, in a child) asking for --realtime: refused, the
    capability and the risk named, no exception."""
    code = (
        "import os, sys\n"
        "sys.path.insert(0, 'tests')\n"
        "from test_tty_worker_status import _status_of\n"  # imported first: as nobody, the
        "from tvsd.hw.mcu.settings import McuSettings\n"  # interpreter's files may be unreadable
        "_status_of(McuSettings(tty_workers='off'), io_priority=60)\n"  # (and what open imports)
        "os.setresuid(65534, 65534, 65534)\n"  # root's capabilities go with uid 0
        "print(_status_of(McuSettings(), io_priority=60))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    want = f"refused: Operation not permitted (needs CAP_SYS_NICE): {TTY_RISK}"
    assert out.stdout.strip() == want, out.stdout


def test_no_unbound_worker_found_is_not_granted(tmp_path: Path) -> None:
    """A /proc with no kworker/u* thread (a kernel that names them otherwise, a container): the
    status says none were found, not "granted (…, 0 workers)" (review)."""
    boost = TtyWorkerBoost("nice", period_s=100.0, proc=tmp_path)
    status = boost.start()
    boost.stop()
    assert status.startswith("none found"), status
