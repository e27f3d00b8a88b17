"""The stale-input check of the control kernel: hold on late input, latch on a stopped MCU.

On Linux every read of a tty (a real UART's RX as much as the SIL's pty) waits for the kernel's
tty flip-buffer work, a normal-priority kworker: CPU load delays it by tens of ms, and the MCU's
state frames then arrive late, in a burst, although the MCU sent every one on time. A stale
measurement therefore does not prove the MCU stopped. So, once the newest frame is older than
K_STALE_NS (mcu.link_timeout_ms) while the drive is commanded, the kernel *holds*: command 0 and
PWM 0 behind each heartbeat (tvsd.control.link_tx), exactly the safe state, but not latched.
The frames that come after decide:

- their chain is unbroken since the last frame before the hold (no frame missing by SEQ, every
  state frame one state period of the MCU's own clock after the previous: the I/O side's
  K_CHAIN_NS, the arrival of the chain's first frame, is not newer than that frame) and the MCU's
  stamps reach the present (K_DUE_NS, when the newest frame was due by them, within K_STALE_NS of
  now): the MCU was alive and only the input was late. Control resumes from the measurement
  (the law's references restart where the shaft is, at its speed) and the hold is counted.
- the chain broke (frames missing, a tick jump, a restarted MCU): latch FAULT_GAP.
- nothing reached the present within K_HOLD_MAX_NS (mcu.link_lost_ms) of the last frame before
  the hold: latch FAULT_STALE, as the link reports the loss.

K_HOLD_MAX_NS 0 (or no measurement ever written) latches FAULT_STALE at the stale limit itself.
Either latch keeps K_FAULT_NS at the hold's start: the safe state began there.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tvsd.control.words import (
    FAULT_GAP,
    FAULT_STALE,
    K_FAULT,
    K_FAULT_MEAS_NS,
    K_FAULT_NS,
    K_HB_NEXT_NS,
    K_HELD,
    K_HOLD_LONGEST_NS,
    K_HOLD_MAX_NS,
    K_HOLD_REF_NS,
    K_HOLD_START_NS,
    K_HOLD_TOTAL_NS,
    K_HOLDS,
    K_LATCH_NS,
    K_MEAS_NS,
    K_STALE_NS,
)


@njit(cache=True, nogil=True)
def _latch(ints: np.ndarray, code: int, wake: int, since: int, meas: int) -> None:
    ints[K_LATCH_NS] = wake
    ints[K_FAULT] = code
    ints[K_FAULT_NS] = since
    ints[K_FAULT_MEAS_NS] = meas
    ints[K_HELD] = 0


@njit(cache=True, nogil=True)
def check_input(ints: np.ndarray, wake: int, commanded: bool, due_ns: int, chain_ns: int) -> bool:
    """One tick's verdict on the input, while no fault is latched (`due_ns`, `chain_ns`: the
    measurement's, read in its seqlock). True on the tick a hold ends in a resume: the law then
    restarts from the measurement."""
    stale = ints[K_STALE_NS]
    if ints[K_HELD] != 0:
        ref = ints[K_HOLD_REF_NS]
        if chain_ns > ref:
            _latch(ints, FAULT_GAP, wake, ints[K_HOLD_START_NS], ref)
        elif wake - due_ns <= stale:
            held = wake - ints[K_HOLD_START_NS]
            ints[K_HOLDS] += 1
            ints[K_HOLD_TOTAL_NS] += held
            if held > ints[K_HOLD_LONGEST_NS]:
                ints[K_HOLD_LONGEST_NS] = held
            ints[K_HELD] = 0
            return True
        elif wake - ref > ints[K_HOLD_MAX_NS]:
            _latch(ints, FAULT_STALE, wake, ints[K_HOLD_START_NS], ref)
        return False
    meas = ints[K_MEAS_NS]
    if commanded and stale > 0 and wake - meas > stale:
        ints[K_HB_NEXT_NS] = wake  # the next heartbeat, with PWM 0 behind it, goes now
        if ints[K_HOLD_MAX_NS] > 0 and meas > 0:
            ints[K_HOLD_REF_NS] = meas
            ints[K_HOLD_START_NS] = wake
            ints[K_HELD] = 1
        else:
            _latch(ints, FAULT_STALE, wake, wake, meas)
    return False
