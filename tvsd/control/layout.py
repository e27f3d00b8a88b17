"""The robust law's parameter words, laid out once for every kernel that runs the law.

The control thread's `vals` array (tvsd.control.runner) and the offline simulation's controller
array (tvsd.sim.closed_loop) both begin with these words; each appends its own after N_LAW. Only
`pack_law`, `write_gains` and `read_gains` write or read the gains, so a gain set from the YAML
reaches a kernel in three steps: config.Gains → Setup.gains → `pack_law`.
"""

from __future__ import annotations

import numpy as np

from tvsd.config import Gains
from tvsd.control.setup import Setup

# MODE: MODE_OFF (the runner commands 0; the simulation applies its open-loop input), MODE_POSITION
# (REF is the angle, rad) or MODE_SCAN (REF is the speed, rev/s).
MODE, REF, GP, GD, GR, G0, UMAX, ACCEL, MAXLAG, FF = range(10)
N_LAW = 10
MODE_OFF, MODE_POSITION, MODE_SCAN = 0, 1, 2

# The excitation table (tvsd.control.excitation → Runner.set_excitation), one row per table period:
# EXC_RPS is added to the scanning speed reference (rev/s, before the ramp), EXC_VOLTS to the law's
# output (V, then clipped at ±UMAX). The loop plays it in scanning mode only.
EXC_RPS, EXC_VOLTS = 0, 1
N_EXC = 2


def write_gains(words: np.ndarray, gains: Gains) -> None:
    words[GP], words[GD], words[GR], words[G0] = gains.as_tuple()


def read_gains(words: np.ndarray) -> Gains:
    return Gains(Gp=float(words[GP]), Gd=float(words[GD]), Gr=float(words[GR]), G0=float(words[G0]))


def pack_law(words: np.ndarray, setup: Setup, mode: int = MODE_OFF, ref: float = 0.0) -> None:
    """Fill the law's words (the first N_LAW of `words`) from a drive set-up."""
    words[MODE] = mode
    words[REF] = ref
    write_gains(words, setup.gains)
    words[UMAX] = setup.u_max
    words[ACCEL] = setup.scan_accel_rps2
    words[MAXLAG] = setup.max_lag_rad
    words[FF] = 1.0 if setup.scan_feedforward else 0.0
