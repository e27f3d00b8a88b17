"""A drift is a trend: the drifting parameter's estimates on separate time windows, tested for a
line through them against their own scatter (issue 12: "drift by windowed refits that agree in
trend").

The decision's drift block (the parameter's column × t/T) gains on anything slow that correlates
with time: a parameter that wanders, a step, low-frequency noise. What only a drift does is move
the parameter steadily. So the record is cut into K windows and the parameter gets one coefficient
per window — its column split by window, every other coefficient of the baseline shared by the
whole record (it does not drift under this hypothesis, and a window alone does not pin it: refit
per window, damping, Coulomb, Stribeck and the absorber's shapes traded with each other, and the
windows' scatter hid a 15 % drift). The K estimates come with their joint covariance Σ (one GLS
fit). A line a + b·t through them by generalised least squares gives the slope b and, from its
lack of fit Q (χ² with K − 2 degrees of freedom if the windows differ by their noise alone), the
overdispersion φ = max(1, Q/(K − 2)): what the windows scatter beyond their stated errors (model
misfit, coloured noise) widens the slope's error by √φ, and the slope's t is then judged against
Student's t with K − 2 degrees of freedom (quasi-likelihood) — the windows' own scatter sets the
bar, so a wandering parameter or a resonance that shifts a window's estimate does not make a trend.

Multiplicity: the decision scanned three parameters (R, kv, friction) and the windows test the one
it chose, so the test's level is α/3 (Bonferroni). The trend must also have the drift block's sign.

A step is not a drift: the best single change point through the window estimates (two levels)
must not fit them significantly better than the line (its lack of fit Q_step against Q_line, in
units of the step model's per-degree scatter; F(1, K − 2) at α — the change point's scan makes this
lenient to the step, so a true line is rarely refused).

A window the record does not pin (its error given the other windows at least the drift's whole change) cannot
show the trend it is to confirm and is left out of the line; at least MIN_WINDOWS must remain.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D

WINDOWS = 10  # 3 s windows of a 30 s record: K − 2 = 8 degrees of freedom for the scatter
MIN_WINDOWS = 4
ALPHA = 0.05
PARAMETERS = 3  # R, kv, friction: the decision's scan (Bonferroni)
MIN_ROWS_PER_WINDOW = 50


@dataclass(frozen=True)
class Trend:
    """The windows' estimates and the tests' figures (reported, and traced by the matrix tools)."""

    centres: np.ndarray  # window centres as a share of the record
    est: np.ndarray
    se: np.ndarray
    slope: float  # the parameter's change over the whole record (t/T from 0 to 1)
    t: float  # slope / its error, widened by √φ
    df: int
    phi: float  # overdispersion: the windows' scatter about the line beyond their errors
    t_crit: float
    step_f: float  # how much better the best step fits than the line (F with 1, K − 2 df)
    f_crit: float
    agrees: bool

    def as_dict(self) -> dict[str, object]:
        return {
            "windows": len(self.est),
            "slope": self.slope,
            "t": round(self.t, 3),
            "df": self.df,
            "phi": round(self.phi, 3),
            "t_crit": round(self.t_crit, 3),
            "step_f": round(self.step_f, 3),
            "f_crit": round(self.f_crit, 3),
            "agrees": self.agrees,
        }


def _split_columns(design: D.Design, parameter: str) -> list[int]:
    """The baseline columns that carry the parameter: the input gain's two (R), damping (kv),
    Coulomb (friction)."""
    if parameter == "R":
        return [0, 1]
    return [design.names.index("c" if parameter == "kv" else "f")]


def windows(design: D.Design, out: C.Outcome, parameter: str, k: int = WINDOWS) -> tuple[np.ndarray, ...]:
    """Per window: its centre (share of the record), the parameter's estimate and the joint
    covariance of the estimates, from one fit with the parameter's columns split by window and
    the rest shared. Windows with too few kept rows are merged into no estimate (left out)."""
    t = design.prep.t_rows
    t0, t1 = float(t[0]), float(t[-1])
    edges = np.linspace(t0, t1 + 1e-9, k + 1)
    cols = _split_columns(design, parameter)
    shared = [j for j in range(design.X.shape[1]) if j not in cols]
    blocks, centres = [], []
    for lo, hi in itertools.pairwise(edges):
        inside = (t >= lo) & (t < hi)
        if np.count_nonzero(inside & out.keep) < MIN_ROWS_PER_WINDOW:
            continue
        blocks.append(design.X[:, cols] * inside[:, None])
        centres.append((0.5 * (lo + hi) - t0) / max(t1 - t0, 1e-12))
    if not blocks:
        return np.zeros(0), np.zeros(0), np.zeros((0, 0))
    X = np.column_stack([design.X[:, shared], *blocks])
    fit = C.gls(design.y, X, out.ar, out.keep)
    m, w = len(shared), len(cols)
    # The estimate of window i: the sum of its split columns' coefficients (R: a₀ + a₁).
    L = np.zeros((len(blocks), X.shape[1]))
    for i in range(len(blocks)):
        L[i, m + i * w : m + (i + 1) * w] = 1.0
    return np.array(centres), L @ fit.theta, L @ fit.cov @ L.T


def trend(centres: np.ndarray, est: np.ndarray, cov: np.ndarray, sign: float, alpha: float = ALPHA) -> Trend:
    """The trend test above on given window estimates (`sign`: the drift block's coefficient, the
    parameter's whole change over the record in the estimates' units)."""
    se = _contrast_se(cov)
    pinned = np.isfinite(est) & (se < abs(sign)) & (se > 0)
    x, y, S = centres[pinned], est[pinned], cov[np.ix_(pinned, pinned)]
    n = len(x)
    df = n - 2
    a = alpha / PARAMETERS
    nan = math.nan
    if n < MIN_WINDOWS:
        return Trend(x, y, se[pinned], nan, nan, df, nan, nan, nan, nan, False)
    W = np.linalg.pinv(S)
    q_line, beta, var_b = _gls_line(x, y, W)
    phi = max(1.0, q_line / df)
    tval = beta / math.sqrt(phi * var_b) if var_b > 0 else nan
    t_crit = float(stats.t.ppf(1 - a / 2, df))
    # The best single change point: two levels, split between windows j−1 and j.
    q_step = min(_gls_levels(y, W, j) for j in range(1, n))
    s2 = max(q_step / df, 1.0)
    step_f = (q_line - q_step) / s2
    f_crit = float(stats.f.ppf(1 - alpha, 1, df))
    ok = bool(math.isfinite(tval) and beta * sign > 0 and abs(tval) > t_crit and step_f <= f_crit)
    return Trend(x, y, se[pinned], beta, tval, df, phi, t_crit, step_f, f_crit, ok)


def _contrast_se(cov: np.ndarray) -> np.ndarray:
    """Each window's error given all the others (1/√ of its diagonal precision): the estimates
    share the baseline's uncertain level (a window's own error, 0.0097, was 7× the 0.0014
    between windows of a kv drift whose whole change was 0.0057, closed-loop matrix seed 710021),
    and only what a window adds to the others can carry a trend. One poorly determined window
    does not make the others' look poor (it would, against the others' plain mean)."""
    if len(cov) < 2:
        return np.sqrt(np.clip(np.diag(cov), 0.0, None))
    prec = np.diag(np.linalg.pinv(cov))
    return np.where(prec > 0, 1.0 / np.sqrt(np.maximum(prec, 1e-300)), np.inf)


def _gls_line(x: np.ndarray, y: np.ndarray, W: np.ndarray) -> tuple[float, float, float]:
    A = np.column_stack([np.ones_like(x), x])
    M = np.linalg.pinv(A.T @ W @ A)
    b = M @ A.T @ W @ y
    r = y - A @ b
    return float(r @ W @ r), float(b[1]), float(M[1, 1])


def _gls_levels(y: np.ndarray, W: np.ndarray, j: int) -> float:
    A = np.zeros((len(y), 2))
    A[:j, 0] = 1.0
    A[j:, 1] = 1.0
    b = np.linalg.pinv(A.T @ W @ A) @ A.T @ W @ y
    r = y - A @ b
    return float(r @ W @ r)


def agrees(design: D.Design, out: C.Outcome, parameter: str, sign: float) -> Trend:
    """The windows of `parameter` trend the drift's way (the absorber's shapes, in design.X, are
    shared like every other coefficient that does not drift)."""
    c, e, s = windows(design, out, parameter)
    return trend(c, e, s, sign)
