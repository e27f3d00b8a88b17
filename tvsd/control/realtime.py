"""What the control thread asks the OS for (SCHED_FIFO, one CPU, locked memory), and what it got."""

from __future__ import annotations

import ctypes
import os
from dataclasses import dataclass

MCL_CURRENT, MCL_FUTURE, MCL_ONFAULT = 1, 2, 4
# The memory lock's modes (lock_memory); $TVSD_MLOCK picks one, "none" too: a measurement knob
# (docs/measurements/stall.md: the soak's A/B).
MLOCK_MODES = ("onfault", "future", "current")
ENV_MLOCK = "TVSD_MLOCK"
MLOCK_DEFAULT = "onfault"  # the soak's 627 ms stall: docs/measurements/stall.md


def mlock_mode() -> str:
    """The mode asked for: $TVSD_MLOCK if it names one, else the default."""
    mode = os.environ.get(ENV_MLOCK, "").strip()
    return mode if mode in MLOCK_MODES or mode == "none" else MLOCK_DEFAULT


def lock_memory(mode: str) -> str:
    """Lock the process's memory so that the control loop takes no page fault; what was granted.

    Every mode first locks and populates what is mapped now (MCL_CURRENT): the loop's arrays,
    its thread's stack, the libraries' code — what the loop touches exists before it runs.
    Then, for mappings made later:
    - "future" (MCL_FUTURE): each is populated in full inside the mmap() that makes it, under the
      process's memory-map lock; any other thread that maps, unmaps or faults waits for all of it
      (on this VM ~12 ms a MiB of fresh memory: a 50 MB reply buffer stands the process ~0.6 s);
    - "onfault" (MCL_FUTURE | MCL_ONFAULT): each page is locked when first touched, by the thread
      that touches it, one fault at a time;
    - "current": later mappings are not locked (faulted in by whoever touches them).
    """
    libc = ctypes.CDLL(None, use_errno=True)
    calls = {
        "current": [MCL_CURRENT],
        "future": [MCL_CURRENT | MCL_FUTURE],
        "onfault": [MCL_CURRENT, MCL_FUTURE | MCL_ONFAULT],  # the 2nd leaves current mappings locked
    }[mode]
    for flags in calls:
        if libc.mlockall(flags) != 0:
            err = ctypes.get_errno()
            return f"refused: {os.strerror(err)} (needs CAP_IPC_LOCK or a larger `ulimit -l`)"
    return f"granted ({mode})"


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
    mode = mlock_mode()
    mem = "not requested" if not lock or mode == "none" else lock_memory(mode)
    return Realtime(fifo, aff, mem)


# Without --realtime every thread of tvsd (the 10 kHz control loop, which writes the MCU's
# heartbeats), of the SIL devices and the kernel's tty workers shares the CPU with any other
# program. Measured beside 2 `yes` loops (docs/measurements/siltiming.md): heartbeats up to 164 ms
# apart, the loop missing 40 % of its ticks, the firmware's watchdog (50 ms) cutting within seconds.
# That cut is the firmware doing its job for a starved host, so no setting keeps such a daemon
# scanning: the user is told at start, with the fix.
def not_realtime_warning(how: str) -> str:
    """The start-up warning of a daemon running `how` ("without --realtime", "with --realtime
    refused"): the risk and the fix, one line."""
    return (
        f"tvsd: WARNING: running {how}: the control loop, which sends the MCU's heartbeat, shares "
        "the CPU with every other program. A CPU-heavy program beside it (a compile, `yes`) delays "
        "heartbeats past the firmware's watchdog: the MCU cuts PWM and laser (fault mcu_watchdog), "
        "state frames come late (mcu_stale), and the drive stops. Fix: start tvsd with --realtime, "
        "as root or with CAP_SYS_NICE and CAP_IPC_LOCK (the systemd unit grants both)."
    )
