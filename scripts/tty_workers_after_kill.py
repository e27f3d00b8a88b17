"""What a daemon killed by SIGKILL leaves of the tty-worker boost, and what the next start does.

Root (or CAP_SYS_NICE). A child process raises the kernel's unbound kworkers as `tvsd --realtime`'s
MCU link does (TtyWorkerBoost, state file in a temporary runtime dir where the code has one), is
killed with SIGKILL, then a new McuLink opens on a pty with that runtime dir (as the next daemon's
start does). Prints one JSON line: workers the child raised, still raised after the kill, and
still raised after the next open. docs/measurements/ttyrestore.md.

    sudo .venv/bin/python scripts/tty_workers_after_kill.py [--from-normal]

--from-normal: first put every fair-scheduled unbound worker at nice 0, as the pool makes them (a
live boost elsewhere, e.g. a --realtime daemon, raises them again within its 1 s period): the
child then has workers to raise even where an earlier kill left them all at nice -20.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import tempfile
import tty
from pathlib import Path

from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.tty_workers import NICE, unbound_workers

CHILD = (
    "import sys, time, inspect\n"
    "from pathlib import Path\n"
    "from tvsd.hw.mcu.tty_workers import TtyWorkerBoost\n"
    "has = 'state_dir' in inspect.signature(TtyWorkerBoost).parameters\n"
    "kw = {'state_dir': Path(sys.argv[1])} if has else {}\n"
    "b = TtyWorkerBoost(period_s=0.1, **kw)\n"
    "b.start()\n"
    "print(' '.join(map(str, sorted(b.changed))), flush=True)\n"
    "time.sleep(120)\n"
)


def raised(pids: list[int]) -> list[int]:
    out = []
    for pid in pids:
        try:
            if os.getpriority(os.PRIO_PROCESS, pid) <= NICE:
                out.append(pid)
        except OSError:
            continue
    return out


async def open_link(port: str, state_dir: Path) -> None:
    try:
        link = McuLink(McuSettings(port=port), state_dir=state_dir)  # type: ignore[call-arg]
    except TypeError:  # the code before the state file: no runtime dir to look in
        link = McuLink(McuSettings(port=port))
    await link.open()
    await link.close()


def main() -> int:
    if "--from-normal" in sys.argv[1:]:
        for pid in unbound_workers():
            try:
                if os.sched_getscheduler(pid) == os.SCHED_OTHER:
                    os.setpriority(os.PRIO_PROCESS, pid, 0)
            except OSError:
                continue
    with tempfile.TemporaryDirectory() as run_dir:
        child = subprocess.Popen([sys.executable, "-c", CHILD, run_dir], stdout=subprocess.PIPE, text=True)
        assert child.stdout is not None
        changed = [int(p) for p in child.stdout.readline().split()]
        child.send_signal(signal.SIGKILL)
        child.wait(10)
        files = sorted(p.name for p in Path(run_dir).iterdir())
        after_kill = raised(changed)
        master, slave = os.openpty()
        tty.setraw(slave)
        try:
            asyncio.run(open_link(os.ttyname(slave), Path(run_dir)))
        finally:
            os.close(slave)
            os.close(master)
        print(
            json.dumps(
                {
                    "unbound_workers": len(unbound_workers()),
                    "raised_by_child": len(changed),
                    "state_files_after_kill": files,
                    "still_raised_after_kill": len(after_kill),
                    "still_raised_after_next_open": len(raised(after_kill)),
                    "state_files_after_next_open": sorted(p.name for p in Path(run_dir).iterdir()),
                }
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
