"""A command held on levels: what a constant per level explains is the drive's, not the vibration's.

A staircase (or a staircase with a PRBS on it) holds the recorded command on a few exact values.
Any static error of the drive on the way from the recorded command to the torque — the bridge's
PWM resolution (an 8-bit bridge applies each level with its own constant error of up to half a
step, which the recorded, unquantised command does not show), a gain that differs per level, an
offset — is then constant over each hold: in the equation's residual a piecewise-constant
acceleration that jumps at the level switches, whose spectrum falls as 1/f² above the holds'
rate. That is exactly a low-pass (Ornstein–Uhlenbeck) shape, so the colour test names it
`colored_noise` (τ ≈ the holds), though the vibration is white: outsider nulls with an 8- or
10-bit PWM, τ 37–253 ms at z 146–406, `none` with the PWM taken out of the same draw
(docs/measurements/outsider2.md).

The spectral tests therefore see the residual less its least-squares projection on one indicator
column per held level (the indicator through the same band filter and decimation as the command:
`Prepared.band_rows`). In open loop the command does not depend on the vibration, so the
projection takes K degrees of freedom of n rows from a white vibration (K ≪ n, and at the holds'
rate, below the spectral band's lowest bins when holds last over a second); in closed loop the
command answers the noise and nothing is projected (the colour is not judged there anyway).
"""

from __future__ import annotations

import numpy as np

from tvsd.analysis.gls import gls
from tvsd.analysis.prep import Prepared

MAX_LEVEL_DOF = 0.02  # at most this share of the rows' degrees of freedom go to the levels
# and at most this many levels: the refit holds rows × (columns + K) in a few copies, and the
# share alone let a 10-min staircase of 0.3 s holds bring 2000 columns (≈ 10 GB; 4 min took 76 s,
# 1.6 GB), past the rows × ~140 columns memory.check budgets; 256 levels over 10 min take 53 s,
# 1.35 GB (docs/measurements/review4.md). The outsider bench's staircases (≤ 120 s, holds
# ≥ 0.8 s, a PRBS doubling the levels) hold ~150.
MAX_LEVELS = 256


def held_levels(u: np.ndarray) -> np.ndarray:
    """The command's values that it holds (equal at two consecutive samples), sorted."""
    same = u[1:] == u[:-1]
    return np.unique(u[1:][same])


def usable_levels(u: np.ndarray, closed: bool, n_rows: int) -> np.ndarray | None:
    """The held levels to project on, None when the command is not held on levels (a multisine,
    closed loop) or holds more of them than MAX_LEVEL_DOF of `n_rows` or MAX_LEVELS allows."""
    if closed:
        return None
    u = np.asarray(u, dtype=float)
    levels = held_levels(u)
    if len(levels) < 2 or len(levels) > min(MAX_LEVEL_DOF * n_rows, MAX_LEVELS):
        return None
    held = np.zeros(len(u), dtype=bool)
    held[1:] = u[1:] == u[:-1]
    held[:-1] |= held[1:]
    if held.mean() < 0.5:  # mostly a moving command with a few repeated values: no staircase
        return None
    return levels


def level_columns(prep: Prepared) -> np.ndarray | None:
    """Rows × K: one band-filtered indicator per held level (usable_levels), or None."""
    u = np.asarray(prep.data.u, dtype=float)
    levels = usable_levels(u, "omega_ref" in prep.data.refs, len(prep.t_rows))
    if levels is None:
        return None
    return np.column_stack([prep.band_rows((u == v).astype(float)) for v in levels])


def without_levels(
    prep: Prepared,
    keep: np.ndarray,
    residual: np.ndarray,
    X: np.ndarray | None = None,
    ar: np.ndarray | None = None,
) -> np.ndarray:
    """The residual rows less what a constant per held command level explains (over `keep`).
    With the model's columns `X` and its whitening `ar`: the residual of the model extended by the
    levels, refitted as the doctor fits (GLS, whose residual is linear in y: the residual's own
    GLS fit on [X, C] is the change) — the fit took a share of the levels' error into its
    coefficients, and the speed's transient in each hold then leaves a low-pass of the mechanical
    time constant that the levels alone do not take out (o12067: colour p 1e-7 → 1.0). An
    unweighted refit on [X, C] is not that: its coefficients follow the encoder's quantisation
    at the band's top and move the low end (o13049: colour p 0.15 → 6e-6)."""
    C = level_columns(prep)
    if C is None or not keep.any():
        return residual
    if X is not None and ar is not None:
        XC = np.column_stack([X, C])
        return np.asarray(np.where(keep, residual - XC @ gls(residual, XC, ar, keep).theta, residual))
    coef, *_ = np.linalg.lstsq(C[keep], residual[keep], rcond=None)
    return np.asarray(np.where(keep, residual - C @ coef, residual))
