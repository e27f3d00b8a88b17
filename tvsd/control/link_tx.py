"""The MCU frames the control kernel writes itself: the heartbeat, and PWM 0 while it holds the
safe state. Nopython, nogil, allocation-free: called once a tick by tvsd.control.kernel.

Why here and not on the link's I/O thread: the heartbeat is what keeps the firmware's watchdog
from cutting PWM and laser, and it must mean "the control loop is alive", nothing more. A Python
thread sends only when it has the GIL, and C code holding the GIL (a catastrophic-backtracking
``re`` match, a large ``json.dumps``, pickle, some numpy calls) kept the I/O thread's heartbeat
47–70 ms late (`tvsctl bench --only mcu_io`). The kernel needs no GIL: a live kernel means a
live heartbeat, a stopped one none, and the firmware cuts within its watchdog.

While the loop's fault or its late-input hold (tvsd.control.hold) keeps command 0 (a stale
measurement: the I/O thread, which feeds the measurement and sends the PWM duty, may itself be
starved), every heartbeat is followed by a
`pwm_set 0` in the same write(): the kernel keeps the watchdog quiet only while the motor is
commanded what the loop decided, never the last duty the starved I/O thread sent.

The frames share the port with the I/O thread through tvsd.hw.mcu.shared_tx (one write per
frame under its mutex, never blocking here: a busy port means "next tick"). A heartbeat's
`host_us` is CLOCK_MONOTONIC in µs when it was built, so the receiver places its ack for the
round trip and the clock sync without a table of what was sent (tvsd.hw.mcu.receiving).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tvsd.control import latency as L
from tvsd.control.words import (
    K_CUTS_SENT,
    K_FAULT,
    K_HB_GAP_MAX_NS,
    K_HB_LAST_NS,
    K_HB_LATE_MAX_NS,
    K_HB_NEXT_NS,
    K_HB_PERIOD_NS,
    K_HB_SENT,
    K_HELD,
    K_TX_ERRORS,
    K_TX_HB,
    K_TX_HB_ID,
    K_TX_LEN,
    K_TX_OFF,
    K_TX_PWM_ID,
    K_TX_SEQ,
    K_TX_SYNC,
)
from tvsd.hw.mcu.shared_tx import BUSY, KERNEL_SEQ, WRITER_KERNEL, put_frame, release_torn, tx_write

TX_BUF_BYTES = 32  # a heartbeat (13 bytes) and a pwm_set (11) back to back
EAGAIN = 11


@njit(cache=True, nogil=True)
def _seq(ints: np.ndarray) -> int:
    """The kernel's SEQs alternate, so two of its frames in a row are never taken for a repeat."""
    ints[K_TX_SEQ] ^= 1
    return KERNEL_SEQ + ints[K_TX_SEQ]


@njit(cache=True, nogil=True)
def _push(ints: np.ndarray, tx: np.ndarray, mutex: np.ndarray, buf: np.ndarray, now: int) -> None:
    """Write what is left of the frame(s) in buf; count the heartbeat once the write is whole."""
    off, n = ints[K_TX_OFF], ints[K_TX_LEN]
    r = tx_write(tx, mutex, buf, off, n - off, WRITER_KERNEL, False)
    if r == BUSY or r == -EAGAIN:
        return  # the I/O thread is writing, or the line is full: next tick
    if r < 0:
        ints[K_TX_ERRORS] += 1  # the port is gone or closed: the frame is dropped
        ints[K_TX_LEN] = 0
        return
    ints[K_TX_OFF] = off + r
    if off + r < n:
        return  # the rest next tick (the I/O thread waits for it: shared_tx.TX_TORN)
    ints[K_TX_LEN] = 0
    if ints[K_TX_HB] != 0:
        last = ints[K_HB_LAST_NS]
        if last > 0 and now - last > ints[K_HB_GAP_MAX_NS]:
            ints[K_HB_GAP_MAX_NS] = now - last
        ints[K_HB_LAST_NS] = now
        ints[K_HB_SENT] += 1


@njit(cache=True, nogil=True)
def link_stop(ints: np.ndarray, tx: np.ndarray, mutex: np.ndarray) -> None:
    """The kernel is leaving: a frame of its own still half out is abandoned (the MCU's parser
    resyncs on the next frame), so the I/O thread is not kept waiting for a rest that never comes."""
    if ints[K_TX_LEN] > 0:
        ints[K_TX_LEN] = 0
        ints[K_TX_ERRORS] += 1
        release_torn(tx, mutex, WRITER_KERNEL)


@njit(cache=True, nogil=True)
def link_tick(
    ints: np.ndarray, tx: np.ndarray, mutex: np.ndarray, buf: np.ndarray, ts: np.ndarray, wake: int
) -> None:
    """Once a tick while the heartbeat is on (K_HB_PERIOD_NS > 0): finish a half-written frame,
    or send the heartbeat (with PWM 0 behind it while faulted) when it is due."""
    if ints[K_TX_LEN] > 0:  # even once detached: the I/O thread waits for the rest
        _push(ints, tx, mutex, buf, L.now_ns(ts))
        return
    period = ints[K_HB_PERIOD_NS]
    if period <= 0:
        return
    now = L.now_ns(ts)
    due = ints[K_HB_NEXT_NS]
    if wake < due:
        return
    if wake - due > ints[K_HB_LATE_MAX_NS]:
        ints[K_HB_LATE_MAX_NS] = wake - due
    # on schedule (a late tick does not shift the ones after it), no burst after a long stall
    ints[K_HB_NEXT_NS] = max(due + period, wake + period // 4)
    sync = ints[K_TX_SYNC]
    n = put_frame(buf, 0, sync, _seq(ints), ints[K_TX_HB_ID], (now // 1000) & 0xFFFFFFFF, 4)
    if ints[K_FAULT] != 0 or ints[K_HELD] != 0:
        n += put_frame(buf, n, sync, _seq(ints), ints[K_TX_PWM_ID], 0, 2)
        ints[K_CUTS_SENT] += 1
    ints[K_TX_LEN], ints[K_TX_OFF], ints[K_TX_HB] = n, 0, 1
    _push(ints, tx, mutex, buf, now)
