"""A friction asymmetry that least squares carries alone in closed loop (verdict.name_cause with
rules.asym_ls_alone): the direction split's instrumented confirmation had no power for it
(closed_checks.NO_POWER), so the split must show that it is a property of the direction, not of a
stretch of the record or of the loop's answer to the noise near zero speed.

The decision's block (design.py: ω·1[ω<0] and, without an offset, −1[ω<0]) acts on the rows at
negative speed only. The record is cut into the drift test's K time windows and the block gets one
copy per window that has at least MIN_ROWS kept rows at negative speed — every other coefficient
shared by the whole record, as drift.windows does — so each window estimates the split from its
own visits to the negative direction against the record's positive one. The split is read as one
number, its torque (in the fit's acceleration units) at the negative rows' median speed. It
stands alone when:

- the negative direction is visited in at least MIN_WINDOWS windows: a split that rests on a few
  brief excursions through zero speed is where the noise itself sets the measured direction and
  the loop's answer to it the friction's sign (closed null 910555: z 12.9, ratio 0.48, 2 % of its
  rows at negative speed, a median of 0.1 rad/s there, no window with 50 such rows);
- the windows agree on one level: their lack of fit Q about the weighted mean is within χ²(K − 1)'s
  1 − drift.ALPHA point (they differ by their noise alone: a wander or a step of the friction,
  or a stretch of misfit, scatters them);
- that level has the decision block's sign and its t (its error widened by √φ, φ = max(1,
  Q/(K − 1)), as the drift trend) is beyond Student's t with K − 1 degrees of freedom at the
  decision's own α (calibrate.ALPHA, two-sided): standing alone, the windows are the second
  evidence, judged at the first's level (drift.ALONE_ALPHA's reasoning).

What this does not bound: a bias the loop puts on the split that is the same in every window (a
stationary loop, stationary noise). The closed nulls are the measure of that
(docs/measurements/closed14.md).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis import drift
from tvsd.analysis.gls import gls

WINDOWS = drift.WINDOWS
MIN_WINDOWS = drift.MIN_WINDOWS
MIN_ROWS = drift.MIN_ROWS_PER_WINDOW
ALONE_ALPHA = C.ALPHA


@dataclass(frozen=True)
class Level:
    """The windows' split estimates and the tests' figures (traced by scripts/closed14_nulls.py)."""

    est: np.ndarray
    se: np.ndarray
    level: float  # the windows' weighted mean split
    t: float  # level / its error widened by √φ
    df: int
    phi: float
    q: float  # lack of fit about the level (χ² with K − 1 df for windows that differ by noise)
    q_crit: float
    t_crit: float
    stands: bool

    def as_dict(self) -> dict[str, object]:
        return {
            "windows": len(self.est),
            "level": self.level,
            "t": round(self.t, 3),
            "df": self.df,
            "phi": round(self.phi, 3),
            "q": round(self.q, 3),
            "q_crit": round(self.q_crit, 3),
            "t_crit": round(self.t_crit, 3),
            "stands": self.stands,
        }


def windows(
    design: D.Design, out: C.Outcome, block: np.ndarray, contrast: np.ndarray, k: int = WINDOWS
) -> tuple[np.ndarray, np.ndarray]:
    """Per window that visits the negative direction (≥ MIN_ROWS kept rows there): the split
    `contrast`·θ_window, and the estimates' joint covariance, from one fit (the block split by
    window, the baseline shared)."""
    t = design.prep.t_rows
    neg = design.prep.rows(design.prep.speed) < 0
    edges = np.linspace(float(t[0]), float(t[-1]) + 1e-9, k + 1)
    blocks = []
    for lo, hi in itertools.pairwise(edges):
        inside = (t >= lo) & (t < hi)
        if np.count_nonzero(inside & out.keep & neg) >= MIN_ROWS:
            blocks.append(block * inside[:, None])
    if not blocks:
        return np.zeros(0), np.zeros((0, 0))
    X = np.column_stack([design.X, *blocks])
    fit = gls(design.y, X, out.ar, out.keep)
    m, w = design.X.shape[1], block.shape[1]
    L = np.zeros((len(blocks), X.shape[1]))
    for i in range(len(blocks)):
        L[i, m + i * w : m + (i + 1) * w] = contrast
    return L @ fit.theta, L @ fit.cov @ L.T


def level(est: np.ndarray, cov: np.ndarray, sign: float, alpha: float = ALONE_ALPHA) -> Level:
    """The tests above on given window estimates (`sign`: the whole record's split)."""
    n = len(est)
    df = n - 1
    nan = math.nan
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None)) if n else np.zeros(0)
    if n < MIN_WINDOWS or not np.all(np.isfinite(est)):
        return Level(est, se, nan, nan, df, nan, nan, nan, nan, False)
    W = np.linalg.pinv(cov)
    one = np.ones(n)
    info = float(one @ W @ one)
    if info <= 0:
        return Level(est, se, nan, nan, df, nan, nan, nan, nan, False)
    mu = float(one @ W @ est) / info
    r = est - mu
    q = float(r @ W @ r)
    phi = max(1.0, q / df)
    tval = mu / math.sqrt(phi / info)
    q_crit = float(stats.chi2.ppf(1 - drift.ALPHA, df))
    t_crit = float(stats.t.ppf(1 - alpha / 2, df))
    ok = bool(mu * sign > 0 and abs(tval) > t_crit and q <= q_crit)
    return Level(est, se, mu, tval, df, phi, q, q_crit, t_crit, ok)


def split_level(design: D.Design, out: C.Outcome, block: np.ndarray, coef: np.ndarray) -> Level:
    """The windows' level of the decision's split block (its coefficients `coef`)."""
    w = design.prep.rows(design.prep.speed)
    v = float(np.median(np.abs(w[w < 0]))) if np.any(w < 0) else 0.0
    # The block's columns at ω = −v: ω·1[ω<0] → −v, −1[ω<0] → −1.
    contrast = np.array([-v, -1.0])[: block.shape[1]]
    sign = float(contrast @ np.asarray(coef, dtype=float))
    est, cov = windows(design, out, block, contrast)
    return level(est, cov, sign)


def ls_alone(design: D.Design, out: C.Outcome, block: np.ndarray, coef: np.ndarray) -> bool:
    """In closed loop, a direction split that least squares alone must carry: see the module."""
    return split_level(design, out, block, coef).stands
