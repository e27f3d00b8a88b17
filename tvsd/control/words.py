"""The control kernel's shared arrays: their word numbers, and the recorded tick's layout.

- `ints` (int64): the timing words of tvsd.control.latency, then K_FAULT (0, or why the loop holds
  its safe state: FAULT_OVERRUN, FAULT_STALE), K_STREAK_LIMIT, K_BUSY_NS, K_MEAS_NS (CLOCK_MONOTONIC
  of the latest measurement the I/O side wrote), K_STALE_NS (0: no check), K_FAULT_NS and
  K_FAULT_MEAS_NS (when the fault latched, and the measurement time it judged), K_SAMPLE_NS (when
  the MCU sampled that measurement; 0: unknown, the angle is used as it is), K_MEAS_SEQ (the
  seqlock around φ, ω and that time), the excitation's K_EXC_*, the MCU frames the kernel
  writes itself (K_HB_*, K_TX_*: tvsd.control.link_tx), and the late-input hold (K_HOLD*,
  K_HELD, and K_DUE_NS, K_CHAIN_NS written with each measurement, inside its seqlock).
- `vals` (float64): the law's words (tvsd.control.layout), the measurement V_PHI, V_OMEGA (written
  by the I/O side), outputs V_U … V_DT.
- `exc` (float64, rows × tvsd.control.layout.N_EXC): the excitation table `tvsctl identify` plays.
- `hist`: the lateness histogram; `rec`: a ring of the last ticks (what the law saw and did),
  indexed by tick number (TICK_DTYPE).

These words are this package's own: everything outside tvsd/control steers the loop through the
`Runner` methods (tests/test_runner_boundary.py greps for it).
"""

from __future__ import annotations

import enum

import numpy as np

from tvsd.control import latency as L
from tvsd.control import layout as W

# Runner words after the timing words of tvsd.control.latency.
(K_FAULT, K_STREAK_LIMIT, K_BUSY_NS, K_MEAS_NS, K_STALE_NS, K_FAULT_NS, K_FAULT_MEAS_NS) = range(
    L.N_TIMING, L.N_TIMING + 7
)
K_SAMPLE_NS, K_MEAS_SEQ = L.N_TIMING + 7, L.N_TIMING + 8
K_EXC_T0_NS, K_EXC_STEP_NS, K_EXC_N = L.N_TIMING + 9, L.N_TIMING + 10, L.N_TIMING + 11
# The kernel's own frames to the MCU (tvsd.control.link_tx): the heartbeat schedule (period 0:
# off), what it sent, and the frame it is writing (len 0: none; off: bytes of it already out).
(
    K_HB_PERIOD_NS,
    K_HB_NEXT_NS,
    K_HB_SENT,
    K_HB_LAST_NS,
    K_HB_GAP_MAX_NS,
    K_HB_LATE_MAX_NS,
    K_TX_ERRORS,
    K_TX_SEQ,
    K_TX_LEN,
    K_TX_OFF,
    K_TX_HB,  # the frame being written carries a heartbeat (counted when whole)
    K_TX_SYNC,
    K_TX_HB_ID,
    K_TX_PWM_ID,
    K_CUTS_SENT,  # PWM-0 frames the kernel sent while its fault held the safe state
) = range(L.N_TIMING + 12, L.N_TIMING + 27)
# Late input (tvsd.control.kernel, "hold"): the bound of a hold (0: a stale measurement latches
# at once), whether one holds now, when it began and the newest arrival before it, the counts;
# and what the I/O side writes with each measurement: when the MCU's frame was due (its own
# stamps from the chain's start: the arrival had nothing been late) and when the unbroken
# chain of frames it belongs to began (a break: frames missing, a tick jump, a restart).
(
    K_HOLD_MAX_NS,
    K_HELD,
    K_HOLD_START_NS,
    K_HOLD_REF_NS,
    K_HOLDS,
    K_HOLD_TOTAL_NS,
    K_HOLD_LONGEST_NS,
    K_DUE_NS,
    K_CHAIN_NS,
    K_LATCH_NS,  # when the stale check latched (K_FAULT_NS: when its safe state began)
) = range(L.N_TIMING + 27, L.N_TIMING + 37)
N_INTS = L.N_TIMING + 37
EXC_LEAD_NS = 2_000_000  # an excitation starts this long after it is set: whole rows, from row 0


class LoopFault(enum.IntEnum):
    """Why the loop holds its safe state (command 0) until `clear_fault`."""

    NONE = 0
    OVERRUN = 1  # `streak_limit` late ticks in a row
    STALE = 2  # the newest measurement is older than `stale_after` (with a hold: beyond its bound)
    GAP = 3  # held for late input, the frames came back with a gap: the MCU itself stopped


FAULT_NONE, FAULT_OVERRUN, FAULT_STALE = LoopFault.NONE.value, LoopFault.OVERRUN.value, LoopFault.STALE.value
FAULT_GAP = LoopFault.GAP.value

# vals: the law's words (inputs the I/O side writes), the measurement, then outputs (kernel writes).
V_MODE, V_REF, V_GP, V_GD, V_GR, V_G0, V_UMAX = W.MODE, W.REF, W.GP, W.GD, W.GR, W.G0, W.UMAX
V_ACCEL, V_MAXLAG, V_FF = W.ACCEL, W.MAXLAG, W.FF
V_PHI, V_OMEGA = W.N_LAW, W.N_LAW + 1
(V_U, V_PHI_REF, V_OMEGA_REF, V_DT) = range(W.N_LAW + 2, W.N_LAW + 6)
N_VALS = W.N_LAW + 6
MODE_IDLE, MODE_POSITION, MODE_SCAN = W.MODE_OFF, W.MODE_POSITION, W.MODE_SCAN

# rec columns: one row per tick, row = tick % len(rec); `recent_ticks` names them (TICK_DTYPE).
TICK_FIELDS = ("t", "dt", "phi", "omega", "phi_ref", "omega_ref", "u_ff", "u", "late_us")
R_T, R_DT, R_PHI, R_OMEGA, R_PHI_REF, R_OMEGA_REF, R_UFF, R_U, R_LATE_US = range(len(TICK_FIELDS))
N_REC = len(TICK_FIELDS)
# One tick as the law saw it: t (s since the loop started), dt (the measured step, s), φ and ω
# measured (carried to the tick), φr and ωr, the feedforward u_ff and the command u (V), and how
# late the tick woke (µs).
TICK_DTYPE = np.dtype([(name, "<f8") for name in TICK_FIELDS])
