"""Whether a speed column is an encoder's count difference, and its count step.

An encoder's backward difference lies on a grid of s = 2π/N·fs (N counts per revolution): every
sample a whole number of steps. tvsd.analysis.quantisation builds the colour test's known floor
from s; tvsd.analysis.dataset reads s before it re-times a late speed (the shift moves the samples
off the grid, not the quantisation's power). Kept apart from quantisation.py, which needs prep
(and prep needs dataset)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

GRID_TOL = 1e-3  # |ω/s − round(ω/s)| below this is on the grid (the CSV's 7 digits: ≤ 5e-4 counts)
GRID_SHARE = 0.99  # share of the samples that must be on it
MIN_LEVELS = 3  # a grid needs at least this many distinct count levels to be read from the data


def on_grid(omega: np.ndarray, step: float) -> bool:
    """Whether the speed is a whole number of steps in (almost) every sample."""
    if not (math.isfinite(step) and step > 0):
        return False
    x = omega / step
    return bool(np.mean(np.abs(x - np.round(x)) < GRID_TOL) >= GRID_SHARE)


def read_step(omega: np.ndarray) -> float | None:
    """The grid step the speed is seen to lie on, or None: the smallest gap between its distinct
    levels (levels within 1e-5 relative merged: printing), confirmed by `on_grid`."""
    levels = np.unique(np.abs(omega))
    if len(levels) > len(omega) // 10:  # a continuous signal: nearly every value distinct
        return None
    gaps = np.diff(levels)
    gaps = gaps[gaps > 1e-5 * max(float(levels[-1]), 1e-12)]
    if len(gaps) + 1 < MIN_LEVELS:
        return None
    # The smallest gap is the step only to the CSV's printing: 7 significant digits leave a level
    # near 100 rad/s with 5 decimals, one near 1 with 7, so a gap of two printed levels is off by
    # up to 5e-5 — 0.005 of a step at the 100th count, past GRID_TOL (an undeclared 8192-count
    # encoder's ω, 0.76699 rad/s steps, read as 0.76695 and missed: no floor, `colored_noise`).
    # The whole number of steps of each level is exact, so the step is their least-squares fit.
    rough = float(np.min(gaps))
    k = np.round(levels / rough)
    step = float(levels @ k / (k @ k)) if k @ k > 0 else rough
    return step if on_grid(omega, step) else None


def speed_step(omega: np.ndarray, fs: float, counts: float | None) -> float | None:
    """The speed's count step s = q·fs: from the declared counts per revolution when ω is on that
    grid, else read from ω when no count is declared; None when ω is not a count difference."""
    if counts is not None:
        step = 2 * math.pi / counts * fs
        return step if on_grid(omega, step) else None
    return read_step(omega)


STEP_KEY = "speed_count_step"  # Dataset.meta: the step read before dataset.load re-timed the speed


def recorded_step(omega: np.ndarray, fs: float, meta: Mapping[str, str]) -> float | None:
    """The count step of a speed column as recorded (with the declared counts, if any)."""
    counts = meta.get("encoder_counts_per_rev")
    return speed_step(omega, fs, float(counts) if counts is not None else None)
