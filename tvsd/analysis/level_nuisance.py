"""A per-level error of the drive as a random effect of the null, when the encoder reads the speed.

A bridge applies each held level of a voltage (or duty) command with its own constant error: a
PWM rounds the level to its step (up to half a step), which the recorded command does not show.
Over a hold the shaft settles, so that error is a constant torque per level, inseparable in the
equation from any static map of the command there (on a staircase a clip or a dead zone *is* one
constant per level). Through a noisy tach it was hidden; through the encoder's count difference
it was named as a cause on 3 of 14 such outsider nulls (8-bit bridges, docs/measurements/
outsidereff.md, pwmlevel.md).

So on those files the null model carries it: y = Xβ + Cδ + e with C the band-filtered indicators
of the held levels and δ_k ~ N(0, τ²) per level. The bootstrap's draws of each block's projection
then carry the levels' scatter too (covariance + τ²/σ² · W_qᵀC_r C_rᵀW_q): a cause that is
constant per level is named only when it explains the levels' errors better than a random scatter
of τ does, the split-plot reading (a per-level effect is judged against the spread between levels,
not the rows' noise within them). Causes that change within a hold (a delay, an imbalance) barely
overlap C, so their nulls barely move. τ (`null_term`) is the larger of
- the bridge's bound: half a step of an 8-bit PWM (±127 steps, the coarsest common bridge) over
  its supply — a duty's declared `u_scale`, else twice the largest command (a bridge run to at least
  half its supply at the top level) — as a uniform error's spread, a·h/√3 with a the fitted gain;
- the levels' own scatter, read robustly (a coarser bridge, a gain that differs per level).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tvsd.analysis import command_levels
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.gls import orth, whiten
from tvsd.analysis.prep import Prepared

# The dense rows × levels block is whitened once per test: at most this many cells (80 MB);
# beyond it the encoder is not used for such a command (speed_source keeps the recorded speed).
MAX_CELLS = 10_000_000
PWM_BITS = 8  # the coarsest bridge assumed: ±2^(bits−1) steps over its supply
SUPPLY_OVER_TOP = 2.0  # a voltage's undeclared supply, over its largest command
NOTE = (
    "each of the command's {} held levels may carry its own constant drive error (a PWM's step): "
    "a random effect of the null, so a cause constant per level (a clip, a dead zone) must explain "
    "more than such errors do"
)
MAD_SIGMA = 1.4826  # a normal's σ over its median absolute deviation
MIN_SCATTER = 8  # levels' contrasts needed to read their scatter (a MAD of fewer is noise)
# the levels' estimates: directions of C_r below this share of its largest singular value are
# dropped (the contrasts the baseline nearly spans: their estimates are noise amplified 1/share×;
# at 1e-6 a PRBS staircase read a scatter 10⁸× the bridge's and the resonance null collapsed)
RCOND = 1e-2


@dataclass(frozen=True)
class Levels:
    columns: np.ndarray  # rows × K band-filtered indicators of the held levels
    half_step: float  # the bridge's largest per-level error, in the command's unit (volts)


def held(data: Dataset, n_rows: int) -> np.ndarray | None:
    """The held levels of an open-loop voltage (or duty) command, None otherwise."""
    if data.u_unit != "V" or data.closed_loop:
        return None
    return command_levels.usable_levels(data.u, False, n_rows)


def fits(data: Dataset, n_rows: int) -> bool:
    """Whether the levels' block is small enough to carry (MAX_CELLS)."""
    levels = held(data, n_rows)
    return levels is None or len(levels) * n_rows <= MAX_CELLS


def half_step(data: Dataset) -> float:
    """Half a PWM_BITS step of the bridge's supply (a duty's u_scale, else SUPPLY_OVER_TOP × top)."""
    scale = data.meta.get("u_scale") if data.meta.get("u_unit") == "duty" else None
    supply = float(scale) if scale is not None else SUPPLY_OVER_TOP * float(np.max(np.abs(data.u)))
    return supply / 2**PWM_BITS


def columns(prep: Prepared) -> Levels | None:
    """The held levels' indicators, through the band filter and decimation of every column
    (command_levels' pieces), or None when the command is not held on levels."""
    n_rows = len(prep.t_rows)
    levels = held(prep.data, n_rows)
    if levels is None or len(levels) * n_rows > MAX_CELLS:
        return None
    C = np.zeros((n_rows, len(levels)))
    for j, r0, col in command_levels.pieces(prep, levels):
        C[r0 : r0 + len(col), j] += col
    return Levels(C, half_step(prep.data))


@dataclass(frozen=True)
class NullLevels:
    """The levels as the null sees them: C_r (whitened, less the baseline's span), the per-level
    error's variance bound, and what reading the levels' scatter needs."""

    Cr: np.ndarray  # rows × K
    bound: float  # τ² of the bridge's bound, in units of the whitened noise's variance σ²
    s2: float  # σ²
    pinv: np.ndarray | None  # the levels' least-squares estimator (None: too few to read a scatter)
    noise_var: float  # the median of the levels' estimates' sampling variances

    top: float = math.inf  # τ²/σ² if all of the levels' share of e₀ were scatter (mean square)

    def ratio(self, e: np.ndarray) -> float:
        """τ²/σ² on the residual e: the larger of the bound and the levels' robust scatter."""
        if self.pinv is None:
            return self.bound
        return max(self.bound, self.scatter(self.pinv @ e))

    def scatter(self, delta: np.ndarray) -> float:
        """The robust scatter of the levels' estimates, never above `top`: the levels cannot
        scatter more than their whole share of the residual."""
        spread = MAD_SIGMA * float(np.median(np.abs(delta - np.median(delta))))
        return min((spread**2 - self.noise_var) / self.s2, self.top)

    def ratio_with(self, Wq: np.ndarray, e0: np.ndarray) -> float:
        """τ²/σ² once the block Wq (orthonormal, the baseline's span out) took its share of e₀:
        the between-levels error is what the model *with* the cause leaves (a split-plot F-test's
        denominator), so a cause that moves every level (a drift of R: t·u) is judged against the
        bridge's scatter, not against its own."""
        if self.pinv is None:
            return self.bound
        return max(self.bound, self.scatter(self.pinv @ e0 - (self.pinv @ Wq) @ (Wq.T @ e0)))


def null_term(
    levels: Levels, gain: float, a: np.ndarray, keep: np.ndarray, Q0: np.ndarray, e0: np.ndarray, p: int
) -> NullLevels:
    """The levels under the null. `gain`: the fitted input gain (acceleration per command unit),
    which turns the bridge's bound into an acceleration.

    The levels' own scatter is the MAD of their estimates δ̂ (least squares of e on C_r), less the
    median of their sampling variances σ²/‖c_k‖²: a cause constant per level touches only some
    levels (a clip the top ones, a dead zone the smallest), outliers to the median, so the scatter
    a cause must beat is the bridge's, not its own (a mean square counted the clip in τ)."""
    Cw = whiten(levels.columns, a, keep)
    Cr = Cw - Q0 @ (Q0.T @ Cw)
    Qc, _ = orth(Cw, Q0)
    k = Qc.shape[1]
    proj = Qc.T @ e0
    s2 = (float(e0 @ e0) - float(proj @ proj)) / max(len(e0) - p - k, 1)
    if s2 <= 0 or k == 0:
        return NullLevels(Cr, 0.0, 1.0, None, 0.0)
    bound = (gain * levels.half_step) ** 2 / 3.0 / s2 if math.isfinite(gain) else 0.0
    norms = np.sum(Cr**2, axis=0)
    used = norms > 0
    if k < MIN_SCATTER:
        return NullLevels(Cr, bound, s2, None, 0.0)
    # the levels' contrasts the baseline leaves (k of them): a direction it spans has no estimate
    pinv = np.linalg.pinv(Cr[:, used], rcond=RCOND)
    noise_var = float(np.median(s2 * np.sum(pinv**2, axis=1)))  # each estimate's sampling variance
    top = max(float(proj @ proj) / s2 - k, 0.0) / float(np.sum(norms))  # E|Q_Cᵀe|² = kσ² + τ²‖C_r‖²
    return NullLevels(Cr, bound, s2, pinv, noise_var, top)
