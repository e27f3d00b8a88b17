"""The serial port's write side, shared by the link's I/O thread and the control kernel.

Why two writers: the heartbeat that arms the firmware's watchdog is written by the nogil control
kernel itself (tvsd.control.link_tx), so that nothing holding the GIL — a catastrophic ``re``
match, a huge ``json.dumps``, pickle — can delay it (a Python thread, even SCHED_FIFO, waits for
the GIL: 47–70 ms heartbeat lateness measured by ``tvsctl bench --only mcu_io``). Every other
command still goes from the I/O thread (tvsd.hw.mcu.io_thread).

Why frames never interleave:
- One ``write()`` per frame (or per batch of whole frames). A tty write is atomic against other
  writers: ``tty_write`` → ``iterate_tty_write`` holds the tty's ``atomic_write_lock`` (a mutex)
  for the whole call, across n_tty's chunks, so two writes' bytes never mix on the wire.
- What the kernel cannot guarantee is a *short* write (O_NONBLOCK, output queue full): the rest
  of that frame goes in a later write, and another writer's frame between the two would tear it.
  So both writers go through ``tx_write`` here: under a process-private pthread mutex (in a
  preallocated buffer: GIL-free, callable from nopython code) it refuses to write while the other
  writer owns a torn frame (``TX_TORN``), and records a torn frame of its own. The I/O thread
  takes the mutex only inside nopython code (``tx_write`` releases the GIL), so the kernel's
  ``trylock`` never waits for a thread that waits for the GIL; the kernel never blocks: a busy
  mutex or a torn frame of the I/O thread's means "next tick" (0.1 ms later).
- SEQ: the firmware drops a frame whose SEQ equals the previous one's (a repeat). The kernel's
  frames alternate between KERNEL_SEQ and KERNEL_SEQ + 1, which the I/O thread never uses.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, types

# shared words (int64): who owns a partly written frame, and counters per writer
TX_FD, TX_TORN, TX_IO_BYTES, TX_KERNEL_BYTES, TX_KERNEL_BUSY, TX_IO_BUSY = range(6)
N_TX_WORDS = 8
TORN_NONE, WRITER_IO, WRITER_KERNEL = 0, 1, 2
EBADF = 9
BUSY = -100_000  # tx_write: the other writer holds the port (mutex, or a torn frame of its own)
KERNEL_SEQ = 0xFFFE  # the kernel's SEQs: 0xFFFE, 0xFFFF (the I/O thread's: 0 .. 0xFFFD)
IO_SEQ_MODULUS = KERNEL_SEQ
MUTEX_WORDS = 8  # 64 bytes: sizeof(pthread_mutex_t) is 40 (x86_64) or 48 (aarch64); zero = unlocked

# Typed Any: numba types are not callables to mypy, they are to the nopython compiler.
_write: Any = types.ExternalFunction("write", types.intp(types.int32, types.voidptr, types.uintp))
_lock: Any = types.ExternalFunction("pthread_mutex_lock", types.int32(types.voidptr))
_trylock: Any = types.ExternalFunction("pthread_mutex_trylock", types.int32(types.voidptr))
_unlock: Any = types.ExternalFunction("pthread_mutex_unlock", types.int32(types.voidptr))
_errno_location: Any = types.ExternalFunction("__errno_location", types.CPointer(types.int32)())


def _crc_table() -> np.ndarray:
    table = np.zeros(256, dtype=np.uint32)
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ 0xEDB88320 if c & 1 else c >> 1
        table[i] = c
    return table


CRC_TABLE = _crc_table()  # CRC-32/ISO-HDLC (zlib's), as the protocol's frames carry


@njit(cache=True, nogil=True)
def crc32(buf: np.ndarray, start: int, n: int) -> int:
    """zlib.crc32 of buf[start:start + n] (uint8), allocation-free."""
    c = np.uint32(0xFFFFFFFF)
    for i in range(start, start + n):
        c = CRC_TABLE[(c ^ buf[i]) & 0xFF] ^ (c >> np.uint32(8))
    return int(c ^ np.uint32(0xFFFFFFFF))


@njit(cache=True, nogil=True)
def put_frame(buf: np.ndarray, start: int, sync: int, seq: int, msg_id: int, payload: int, n: int) -> int:
    """Encode one frame at buf[start:] whose payload is the n-byte little-endian `payload`
    (n ≤ 8): SYNC LEN SEQ ID PAYLOAD CRC32, as tvsd.hw.mcu.framing.encode_frame. Returns its size."""
    buf[start] = sync
    buf[start + 1] = n
    buf[start + 2] = seq & 0xFF
    buf[start + 3] = (seq >> 8) & 0xFF
    buf[start + 4] = msg_id
    for i in range(n):
        buf[start + 5 + i] = (payload >> (8 * i)) & 0xFF
    c = crc32(buf, start, 5 + n)
    for i in range(4):
        buf[start + 5 + n + i] = (c >> (8 * i)) & 0xFF
    return 9 + n


@njit(cache=True, nogil=True)
def tx_write(
    tx: np.ndarray, mutex: np.ndarray, buf: np.ndarray, start: int, n: int, who: int, wait: bool
) -> int:
    """write(tx[TX_FD], buf[start:start + n]) under the shared mutex: bytes written, -errno
    (-EBADF once closed), or BUSY (nothing written: the mutex is taken and `wait` is False, or the
    other writer's frame is torn). A short write marks `who` as owning a torn frame until a later
    call writes the rest. The fd is read under the mutex: after `tx_close` nobody writes to it."""
    if wait:
        _lock(mutex.ctypes)
    elif _trylock(mutex.ctypes) != 0:
        tx[TX_KERNEL_BUSY if who == WRITER_KERNEL else TX_IO_BUSY] += 1
        return BUSY
    torn = tx[TX_TORN]
    if torn != TORN_NONE and torn != who:
        tx[TX_KERNEL_BUSY if who == WRITER_KERNEL else TX_IO_BUSY] += 1
        _unlock(mutex.ctypes)
        return BUSY
    fd = tx[TX_FD]
    if fd < 0:
        _unlock(mutex.ctypes)
        return -EBADF
    r = _write(fd, buf[start:].ctypes, n)
    if r < 0:
        r = -_errno_location()[0]
    else:
        tx[TX_KERNEL_BYTES if who == WRITER_KERNEL else TX_IO_BYTES] += r
        tx[TX_TORN] = who if r < n else TORN_NONE
    _unlock(mutex.ctypes)
    return r


@njit(cache=True, nogil=True)
def tx_close(tx: np.ndarray, mutex: np.ndarray) -> None:
    """No write to the fd after this returns (the owner may close it: its number may be reused)."""
    _lock(mutex.ctypes)
    tx[TX_FD] = -1
    tx[TX_TORN] = TORN_NONE
    _unlock(mutex.ctypes)


@njit(cache=True, nogil=True)
def release_torn(tx: np.ndarray, mutex: np.ndarray, who: int) -> None:
    """`who` gives up its half-written frame (the rest will never come)."""
    _lock(mutex.ctypes)
    if tx[TX_TORN] == who:
        tx[TX_TORN] = TORN_NONE
    _unlock(mutex.ctypes)


@njit(cache=True, nogil=True)
def tx_open(tx: np.ndarray, mutex: np.ndarray, fd: int) -> None:
    _lock(mutex.ctypes)
    tx[TX_FD] = fd
    tx[TX_TORN] = TORN_NONE
    _unlock(mutex.ctypes)


_warm = False


def warm_up() -> None:
    """Load (or compile) the functions the I/O thread calls, once per process: the first call
    of a numba function holds the GIL for seconds (measured 3.2 s here), which on a port already
    open stalled the link (the simavr test lost 2.7 s of frames)."""
    global _warm
    if _warm:
        return
    tx, mutex = np.zeros(N_TX_WORDS, dtype=np.int64), np.zeros(MUTEX_WORDS, dtype=np.int64)
    tx_open(tx, mutex, -1)
    tx_write(tx, mutex, np.zeros(1, dtype=np.uint8), 0, 1, WRITER_IO, True)
    release_torn(tx, mutex, WRITER_IO)
    tx_close(tx, mutex)
    _warm = True


class SharedTx:
    """The shared write side of one serial fd: the mutex, the words, the fd (-1: none). Made
    once, before either writer starts (the control kernel holds these arrays for its whole run);
    ``open``/``close`` point it at a port and away again."""

    def __init__(self) -> None:
        warm_up()  # here, before any port is open
        self.mutex = np.zeros(MUTEX_WORDS, dtype=np.int64)
        self.words = np.zeros(N_TX_WORDS, dtype=np.int64)
        self.words[TX_FD] = -1

    def open(self, fd: int) -> None:
        tx_open(self.words, self.mutex, fd)

    def write(self, buf: np.ndarray, start: int, n: int) -> int:
        """The I/O thread's write (waits for the mutex, GIL released); see tx_write."""
        return int(tx_write(self.words, self.mutex, buf, start, n, WRITER_IO, True))

    def close(self) -> None:
        tx_close(self.words, self.mutex)

    @property
    def is_open(self) -> bool:
        return bool(self.words[TX_FD] >= 0)

    @property
    def torn_by_kernel(self) -> bool:
        return bool(self.words[TX_TORN] == WRITER_KERNEL)

    def counters(self) -> dict[str, int]:
        w = self.words
        return {
            "io_bytes": int(w[TX_IO_BYTES]),
            "kernel_bytes": int(w[TX_KERNEL_BYTES]),
            "kernel_busy": int(w[TX_KERNEL_BUSY]),
            "io_busy": int(w[TX_IO_BUSY]),
        }
