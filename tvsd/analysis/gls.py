"""Generalised least squares under an AR noise model: the whitening filter, the whitened fit, and
the projection that leaves a block only what the whitened baseline does not explain.

The baseline's residual rows are not white (the differentiated speed noise rises with frequency; a
coloured vibration falls): an AR(p) model of that residual (Yule–Walker, `ar_filter`) whitens every
column alike, so the Gaussian likelihood of the rows is honest. The decision (tvsd.analysis.calibrate),
its confirmations and the cause's refits all fit through `gls`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter as sig_lfilter


@dataclass(frozen=True)
class GLS:
    theta: np.ndarray
    se: np.ndarray
    rss: float
    n: int
    cov: np.ndarray  # of theta: sums of coefficients (a₀ + a₁) need the off-diagonal terms


def gls(
    y: np.ndarray, X: np.ndarray, ar: np.ndarray, keep: np.ndarray, rows: np.ndarray | None = None
) -> GLS:
    """Least squares on the whitened rows (kept, and inside `rows` when given)."""
    sel = keep if rows is None else keep & rows
    yw, Xw = whiten(y, ar, sel), whiten(X, ar, sel)
    theta, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
    r = yw - Xw @ theta
    rss = float(r @ r)
    n, k = Xw.shape
    try:
        # pinv: a column that is all zero (the Stribeck term of a file that never runs slow) has no
        # variance of its own and must not make every other coefficient's unknown
        cov = rss / max(n - k, 1) * np.linalg.pinv(Xw.T @ Xw)
    except np.linalg.LinAlgError:
        cov = np.full((k, k), math.nan)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return GLS(theta, se, rss, n, cov)


def whitened_rss(y: np.ndarray, X: np.ndarray, theta: np.ndarray, ar: np.ndarray, sel: np.ndarray) -> float:
    r = whiten(y - X @ theta, ar, sel)
    return float(r @ r)


def ar_filter(r: np.ndarray, p: int) -> np.ndarray:
    """Yule–Walker AR(p) of r, as the whitening filter's coefficients."""
    r = r - r.mean()
    n = len(r)
    acf = np.array([float(r[: n - k] @ r[k:]) / n for k in range(p + 1)])
    if acf[0] <= 0:
        return np.array([1.0])
    from scipy.linalg import solve_toeplitz

    phi = solve_toeplitz(acf[:p], acf[1 : p + 1])
    return np.concatenate([[1.0], -phi])


def whiten(x: np.ndarray, a: np.ndarray, keep: np.ndarray) -> np.ndarray:
    return sig_lfilter(a, [1.0], x, axis=0)[keep]


def orth(W: np.ndarray, Q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis of W with the baseline projected out, and that residualised W."""
    W = W - Q0 @ (Q0.T @ W)
    q, r = np.linalg.qr(W)
    good = np.abs(np.diag(r)) > 1e-9 * max(float(np.max(np.abs(np.diag(r)))), 1e-300)
    return q[:, good], W


def clear_memory(keep: np.ndarray, order: int) -> np.ndarray:
    """The rows of `keep` whose AR(order) whitening holds no row out of it, nor the record's
    start: the rows a whitened fit may use (calibrate.test_all for the doctor's AR,
    spectral_fit.refit for the floor's AR(48))."""
    out = np.asarray(keep) > 0
    mask = out.copy()
    for lag in range(1, min(order, len(mask)) + 1):
        out[lag:] &= mask[:-lag]
    out[:order] = False
    return out
