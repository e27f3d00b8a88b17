"""The nonlinear maps' instrumented blocks: E[f(u) | instruments] for the dead zone and the clip.

Closed forms of the Gaussian conditional expectations (`_above`, `_below`, `_expect_clip`,
`_expect_sat`) that `tvsd.analysis.instrument.instrumented(expected=True)` puts in the design in
place of f(û) (docs/measurements/cldz.md, closedsat.md). Split from instrument.py (branch
splits3), unchanged."""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
from scipy.special import ndtr

from tvsd.analysis import design as D
from tvsd.analysis.prep import Prepared

if TYPE_CHECKING:  # instrument.py imports this module: FirstStage is only an annotation here
    from tvsd.analysis.instrument import FirstStage


def expected_maps(design: D.Design, prep: Prepared, fs: FirstStage) -> None:
    """The dead zone's and the clip's instrumented blocks as E[f(u) | instruments], not f(û).

    For a map f that is not linear the valid instrument that carries its information is the
    conditional expectation of f(u) given the instruments (the standard choice for a nonlinear
    function of an endogenous regressor; Kelejian 1971, Amemiya 1974), not f of the expected u:
    û is the reference through the loop's linear response, smoother than u, so |û| crosses a
    clip a little below the law's rail far less often than |u| does, and f(û) correlated
    0.4–0.7 with f(u) on the closed-loop clips of matrix seed 71 that the confirmation refused.
    Here u = clip(u_lin + e, the recorded range) with e ~ N(0, spread²) (spread: the std of
    u − u_lin after the spin-up, one scalar of the file), whose expectations through a dead
    zone and a clip have closed forms (`_expect_clip`, `_expect_sat`). Still a function of the
    reference and the PRBS only (and one scalar), so the bootstrap is still its null; with
    spread → 0 they are f(û)."""
    if fs.u_lin is None or fs.spread <= 0:
        return
    band = prep.band_rows
    mu, sd, (lo, hi) = fs.u_lin, fs.spread, fs.bounds
    opts = design.options
    if "deadzone" in opts:
        opts["deadzone"] = [
            dataclasses.replace(o, block=band(_expect_clip(mu, sd, float(o.effect["u0"]), lo, hi))[:, None])
            for o in opts["deadzone"]
        ]
    if "saturation" in opts:
        opts["saturation"] = [
            dataclasses.replace(o, block=band(_expect_sat(mu, sd, float(o.effect["u_max"]), lo, hi))[:, None])
            for o in opts["saturation"]
        ]


def _above(mu: np.ndarray, sd: float, a: float) -> np.ndarray:
    """E[max(Y − a, 0)] for Y ~ N(mu, sd²)."""
    d = (mu - a) / sd
    return (mu - a) * ndtr(d) + sd * np.exp(-0.5 * d * d) / np.sqrt(2 * np.pi)


def _below(mu: np.ndarray, sd: float, a: float) -> np.ndarray:
    """E[max(a − Y, 0)] for Y ~ N(mu, sd²)."""
    return _above(-mu, sd, -a)


def _expect_clip(mu: np.ndarray, sd: float, x: float, lo: float, hi: float) -> np.ndarray:
    """E[clip(Y, −x, x)] for Y = clip(N(mu, sd²), lo, hi), lo ≤ −x ≤ x ≤ hi (the dead zone's block)."""
    x = min(x, hi, -lo)
    return lo + _above(mu, sd, lo) - _above(mu, sd, x) + _below(mu, sd, -x) - _below(mu, sd, lo)


def _expect_sat(mu: np.ndarray, sd: float, x: float, lo: float, hi: float) -> np.ndarray:
    """E[sgn Y·max(|Y| − x, 0)] for Y = clip(N(mu, sd²), lo, hi) (the clip's block)."""
    pos = _above(mu, sd, x) - _above(mu, sd, hi) if x < hi else np.zeros_like(mu)
    neg = _below(mu, sd, -x) - _below(mu, sd, lo) if -x > lo else np.zeros_like(mu)
    return pos - neg
