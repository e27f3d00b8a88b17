"""What the control thread asks the OS for (SCHED_FIFO, one CPU, locked memory), and what it got."""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Realtime:
    """What the thread asked the OS for and what it got, in plain words."""

    sched_fifo: str
    affinity: str
    mlockall: str


def request_realtime(priority: int = 80, cpu: int | None = None, lock: bool = True) -> Realtime:
    """Call from the thread to be made real-time; each request that fails says why."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        fifo = f"granted (priority {priority})"
    except (PermissionError, OSError) as exc:
        fifo = f"refused: {exc.strerror or exc} (needs root or CAP_SYS_NICE / rtprio limit)"
    allowed = sorted(os.sched_getaffinity(0))
    target = allowed[-1] if cpu is None else cpu
    try:
        os.sched_setaffinity(0, {target})  # pid 0 = this thread on Linux
        aff = f"granted (CPU {target} of {allowed})"
    except OSError as exc:
        aff = f"refused: {exc.strerror or exc} (CPU {target} not in {allowed})"
    if not lock:
        mem = "not requested"
    else:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.mlockall(1 | 2) == 0:  # MCL_CURRENT | MCL_FUTURE: no page faults in the loop
            mem = "granted (current and future pages)"
        else:
            err = ctypes.get_errno()
            mem = f"refused: {os.strerror(err)} (needs CAP_IPC_LOCK or a larger `ulimit -l`)"
    return Realtime(fifo, aff, mem)
