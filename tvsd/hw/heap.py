"""glibc's allocator set so that the daemon's threads, once warm, no longer map memory.

Why (docs/measurements/imureader.md): every mprotect, mmap, munmap, mremap and brk takes the
process's memory-map lock for writing. A Python thread calls them from malloc and free while it
holds the GIL; when the lock is busy (another thread's unmap of a large reply, a populate) the
thread waits in the kernel and every other Python thread waits for it. The IMU reader was caught
so in `mprotect` for 453 ms (docs/measurements/daemonfix.md §4), and traced in soaks: left as
glibc sets it, its arena's heap grew all the time (~7 KiB/s, 84-113 mprotect calls per 135 s:
glibc grows a thread's heap by what each allocation needs, and the reader's freed blocks are
reused on the event loop's thread, which frees its batches: tests/test_imu_heap.py), and one of
those calls waited 100 ms for the lock, held by khugepaged.

`tune()` (daemon start, --realtime): heap memory is no longer handed back while it is under
TRIM_BYTES (no trim, so no regrowth), and allocations up to glibc's largest mmap threshold come
from the heaps (no mmap/munmap pair per large block; glibc's own dynamic threshold stops moving
once a threshold is set, so both are set; the main arena grows by brk at least TOP_PAD_BYTES at a
time). `reserve(nbytes)` on a thread grows that thread's arena once to `nbytes`, touched (under
mlockall's MCL_ONFAULT: locked), and frees it into the arena's top, where it stays: the thread's
later allocations up to that size need no system call and no page fault (pymalloc's own 1 MiB
arenas for small objects are CPython's mmap calls, out of glibc's reach). The cost is memory:
the heaps keep their peak (locked, under --realtime).

`$TVSD_MALLOC=default` leaves glibc as it is (a measurement knob, as $TVSD_MLOCK).
"""

from __future__ import annotations

import ctypes
import os

ENV_MALLOC = "TVSD_MALLOC"
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3  # malloc.h
PARAM_NAMES = {
    M_TRIM_THRESHOLD: "M_TRIM_THRESHOLD",
    M_TOP_PAD: "M_TOP_PAD",
    M_MMAP_THRESHOLD: "M_MMAP_THRESHOLD",
}


def mmap_threshold_max(long_bytes: int) -> int:
    """glibc's DEFAULT_MMAP_THRESHOLD_MAX, the most mallopt(M_MMAP_THRESHOLD) accepts (half a
    thread heap's size): 4 MiB·sizeof(long) on 64-bit (32 MiB), 512 KiB on 32-bit (armhf)."""
    return 512 * 1024 if long_bytes <= 4 else 4 * 1024 * 1024 * long_bytes


MMAP_THRESHOLD_MAX = mmap_threshold_max(ctypes.sizeof(ctypes.c_long))
TRIM_BYTES = 2 * MMAP_THRESHOLD_MAX  # glibc's own dynamic rule: trim at twice the mmap threshold
TOP_PAD_BYTES = 4 << 20  # the main arena grows by brk in steps of at least this
_tuned = False  # tune() succeeded in this process (mallopt's settings are the process's)


def _libc() -> ctypes.CDLL | None:
    """glibc, or None (another C library: musl has no mallopt for these)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
        libc.malloc.restype = ctypes.c_void_p
        libc.malloc.argtypes = [ctypes.c_size_t]
        libc.free.argtypes = [ctypes.c_void_p]
        libc.gnu_get_libc_version.restype = ctypes.c_char_p
    except (OSError, AttributeError):
        return None
    return libc


def wanted() -> bool:
    """Whether the daemon tunes the allocator: unless $TVSD_MALLOC is "default"."""
    return os.environ.get(ENV_MALLOC, "").strip() != "default"


def tune() -> str:
    """Set glibc's thresholds (above); what was granted, in words."""
    if not wanted():
        return f"left as glibc sets it (${ENV_MALLOC}=default)"
    libc = _libc()
    if libc is None:
        return "not glibc: left as it is"
    asked = (
        (M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX),
        (M_TRIM_THRESHOLD, TRIM_BYTES),
        (M_TOP_PAD, TOP_PAD_BYTES),
    )
    done: list[str] = []
    for param, value in asked:  # in order, up to a refusal: never a half-set rule taken as set
        if libc.mallopt(param, value) != 1:
            before = ", ".join(done) or "nothing"
            return f"mallopt refused {PARAM_NAMES[param]} = {value} ({before} set before it); no reserve"
        done.append(PARAM_NAMES[param])
    global _tuned
    _tuned = True
    return f"heaps kept up to {_size(TRIM_BYTES)} free, blocks up to {_size(MMAP_THRESHOLD_MAX)} from them"


def _size(nbytes: int) -> str:
    return f"{nbytes >> 20} MiB" if nbytes >= 1 << 20 else f"{nbytes >> 10} KiB"


def reserve(nbytes: int) -> bool:
    """On the calling thread: grow its arena to `nbytes`, touch every page, free it (kept, after
    tune()). False when not done: tune() not done or refused (a block this large would be its own
    mapping, unmapped at its free), not glibc, no memory."""
    nbytes = min(nbytes, MMAP_THRESHOLD_MAX // 2)  # under the threshold: from the heap, not mmap
    if nbytes <= 0 or not _tuned:
        return False
    libc = _libc()
    if libc is None:
        return False
    block = libc.malloc(nbytes)
    if not block:
        return False
    ctypes.memset(block, 0, nbytes)  # fault every page in now, before the thread's real work
    libc.free(block)
    return True
