"""Where a process's threads are, from the kernel's own files under /proc/<pid>/task/<tid>/.

Read by the stall watches (tvsd.sim.sil_watch, inside the process) and by the soak's outside
sampler (tvsd.sim.proc_watch). None of the files read here takes the process's memory-map lock
(`maps`, `cmdline`, `environ` do), so they answer while the process is blocked on it. `stack`
and `syscall` need ptrace rights over the process (root, or the same user with ptrace_scope 0):
without them they are left out.
"""

from __future__ import annotations

import contextlib
import os
import platform
import re
from typing import Any

# x86_64 numbers of the calls a blocked daemon thread is likely to sit in (others: the number)
_SYSCALLS_X86_64 = {
    0: "read", 1: "write", 7: "poll", 9: "mmap", 10: "mprotect", 11: "munmap", 12: "brk",
    16: "ioctl", 20: "writev", 23: "select", 25: "mremap", 28: "madvise", 35: "nanosleep",
    44: "sendto", 45: "recvfrom", 46: "sendmsg", 47: "recvmsg", 149: "mlock", 151: "mlockall",
    202: "futex", 230: "clock_nanosleep", 232: "epoll_wait", 257: "openat", 262: "newfstatat",
    270: "pselect6", 271: "ppoll", 281: "epoll_pwait", 318: "getrandom", 325: "mlock2",
}  # fmt: skip
_NAMES = _SYSCALLS_X86_64 if platform.machine() == "x86_64" else {}
_FRAME = re.compile(r"^\[<[0-9a-fx]+>\]\s*([^+\s]+)")
STACK_FRAMES = 10


def _read(path: str) -> str | None:
    try:
        with open(path, encoding="ascii", errors="replace") as f:
            return f.read()
    except OSError:
        return None  # the thread ended, or no rights


def tids(pid: int | str = "self") -> list[int]:
    with contextlib.suppress(OSError):
        return sorted(int(t) for t in os.listdir(f"/proc/{pid}/task"))
    return []


def task_stat(pid: int | str, tid: int) -> tuple[str, int, int] | None:
    """(state letter, minor faults, major faults) of one thread."""
    text = _read(f"/proc/{pid}/task/{tid}/stat")
    if text is None:
        return None
    f = text[text.rfind(")") + 2 :].split()  # after "pid (comm) ": field 3 on
    return f[0], int(f[7]), int(f[9])  # state, minflt (10), majflt (12)


def process_faults(pid: int | str = "self") -> dict[str, int] | None:
    """The whole process's page faults (its live and ended threads)."""
    text = _read(f"/proc/{pid}/stat")
    if text is None:
        return None
    f = text[text.rfind(")") + 2 :].split()
    return {"minflt": int(f[7]), "majflt": int(f[9])}


def syscall(pid: int | str, tid: int) -> str | None:
    """The call the thread is blocked in ("futex", "write", a number), "running", or "-1"
    (blocked outside a system call: a page fault, or preempted in user space)."""
    text = _read(f"/proc/{pid}/task/{tid}/syscall")
    if not text:
        return None
    head = text.split()[0]
    if head in ("running", "-1"):
        return head
    with contextlib.suppress(ValueError):
        return _NAMES.get(int(head), head)
    return head


def stack(pid: int | str, tid: int) -> list[str] | None:
    """The thread's kernel stack, function names only, innermost first."""
    text = _read(f"/proc/{pid}/task/{tid}/stack")
    if text is None:
        return None
    out = []
    for line in text.splitlines():
        m = _FRAME.match(line.strip())
        if m:
            out.append(m.group(1))
    return out[:STACK_FRAMES]


def where(pid: int | str, tid: int, with_stack: bool = True) -> dict[str, Any] | None:
    """One thread: its state (R running or runnable, S sleeping, D uninterruptible), the kernel
    function it waits in (wchan), its system call, its faults so far and (not running) its stack."""
    st = task_stat(pid, tid)
    if st is None:
        return None
    out: dict[str, Any] = {"state": st[0], "minflt": st[1], "majflt": st[2]}
    wchan = _read(f"/proc/{pid}/task/{tid}/wchan")
    if wchan and wchan != "0":
        out["wchan"] = wchan
    call = syscall(pid, tid)
    if call is not None:
        out["syscall"] = call
    if with_stack and st[0] != "R":
        frames = stack(pid, tid)
        if frames:
            out["stack"] = frames
    return out


def pressure() -> dict[str, dict[str, int]] | None:
    """The machine's pressure stall totals (µs some / full task stalled since boot) for memory,
    io and cpu, and each CPU's steal time (µs); None where the kernel has neither."""
    out: dict[str, dict[str, int]] = {}
    for res in ("memory", "io", "cpu"):
        text = _read(f"/proc/pressure/{res}")
        if text is None:
            continue
        out[res] = {}
        for line in text.splitlines():
            kind, *fields = line.split()
            for kv in fields:
                k, _, v = kv.partition("=")
                if k == "total":
                    out[res][f"{kind}_us"] = int(v)
    steal = _steal_us()
    if steal:
        out["steal"] = steal
    return out or None


def _steal_us() -> dict[str, int]:
    """Per CPU, µs its virtual CPU was not run by the hypervisor (/proc/stat's steal, in USER_HZ
    ticks): a whole-machine stall that no priority inside can help."""
    text = _read("/proc/stat") or ""
    hz = os.sysconf("SC_CLK_TCK")
    out = {}
    for line in text.splitlines():
        f = line.split()
        if f and f[0].startswith("cpu") and f[0] != "cpu" and len(f) > 8:
            out[f"{f[0]}_us"] = int(f[8]) * 1_000_000 // hz
    return out


def pressure_delta(before: dict[str, Any] | None, after: dict[str, Any] | None) -> dict[str, Any] | None:
    """µs stalled between two `pressure()` readings, per resource and kind."""
    if not before or not after:
        return None
    return {
        r: {k: v - before.get(r, {}).get(k, 0) for k, v in kv.items()}
        for r, kv in after.items()
        if r in before
    }
