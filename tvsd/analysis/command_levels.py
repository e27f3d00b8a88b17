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

from collections.abc import Callable

import numpy as np
from scipy.signal import lfilter

from tvsd.analysis.prep import Prepared, antialias

MAX_LEVEL_DOF = 0.02  # at most this share of the rows' degrees of freedom go to the levels
# and at most this many levels: the refit is linear in the rows (piecewise normal equations) but
# solves a (p + K)² system, O(K³): 1024 levels over 10 min take 1.3 s and 0.23 GB, 2000 took 17 s
# and 4000 1 GB (docs/measurements/levelsfast.md). The dense refit this replaced needed a cap of
# 256 (53 s, 1.35 GB over 10 min, docs/measurements/review4.md). The outsider bench's staircases
# (≤ 120 s, holds ≥ 0.8 s, a PRBS doubling the levels) hold ~150.
MAX_LEVELS = 1024
# a filtered indicator is taken as nil this far below its size (far under the fit's own rounding)
TAIL = 1e-20
# the normal equations' rank cut (singular values, relative, of the equilibrated [X, C]): their
# rounding is ~1e-16 of the largest eigenvalue, i.e. 1e-8 in singular value; lstsq cuts at ~1e-10
RANK_TOL = 1e-7
REFINE = 1


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


def _reach(prep: Prepared) -> int:
    """Full-rate samples past a held stretch beyond which its band-filtered indicator is below
    TAIL of its size: the slowest pole of the band low-pass and of the anti-alias filter each
    decays as ρᵐ (×2 for the polynomial factor of a near-repeated pole; filtfilt runs each both
    ways, which the symmetric window covers), plus the [1, 2, 1]/4 average and one decimation block."""
    filters = [prep.a] + ([antialias(prep.band.decim)[1]] if prep.band.decim > 1 else [])
    m = 0
    for a in filters:
        rho = float(np.max(np.abs(np.roots(a)))) if len(a) > 1 else 0.0
        m += 2 * int(np.ceil(np.log(TAIL) / np.log(rho))) if rho > 0 else 0
    return m + 2 + 2 * prep.band.decim


def _pieces(prep: Prepared, levels: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """(level, first row, band-filtered indicator rows) per cluster of a level's samples: the
    indicators do not overlap before the filter, and each stretch's filtered indicator is nil
    (below TAIL) past `_reach` samples, so a column is the sum of a few short pieces and all of
    them together cost O(samples + K·reach), not O(samples·K)."""
    u = np.asarray(prep.data.u, dtype=float)
    n, q = len(u), prep.band.decim
    lab = np.clip(np.searchsorted(levels, u), 0, len(levels) - 1)
    idx = np.flatnonzero(levels[lab] == u)
    idx = idx[np.argsort(lab[idx], kind="stable")]  # grouped by level, in time within each
    lab = lab[idx]
    reach = _reach(prep)
    # a new cluster at each level change or gap wider than two reaches
    cut = np.flatnonzero((np.diff(lab) != 0) | (np.diff(idx) > 2 * reach + 2 * q)) + 1
    first_row = prep.trim // q
    n_rows = len(prep.t_rows)
    pieces = []
    for s, e in zip(np.r_[0, cut], np.r_[cut, len(idx)], strict=True):
        lo = max(0, int(idx[s]) - reach) // q * q  # on the decimation's phase
        hi = min(n, int(idx[e - 1]) + 1 + reach)
        ind = np.zeros(hi - lo)
        ind[idx[s:e] - lo] = 1.0
        col = prep.decimate(prep.lowpass(ind))
        r0 = lo // q - first_row  # the piece's first row
        a0, a1 = max(0, -r0), min(len(col), n_rows - r0)
        if a1 > a0:
            pieces.append((int(lab[s]), r0 + a0, col[a0:a1].copy()))
    return pieces


def pieces(prep: Prepared, levels: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """`_pieces`: (level, first row, band-filtered indicator rows) per cluster of a level's samples."""
    return _pieces(prep, levels)


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
    at the band's top and move the low end (o13049: colour p 0.15 → 6e-6).

    The fit is solved from its normal equations built piecewise (`_pieces`), so time and memory
    are linear in the rows: the dense rows × (p + K) design of `gls` took 53 s and 1.35 GB for a
    10-min staircase of 256 levels (docs/measurements/levelsfast.md)."""
    u = np.asarray(prep.data.u, dtype=float)
    n_rows = len(residual)
    levels = usable_levels(u, prep.data.closed_loop, n_rows)
    if levels is None or not keep.any():
        return residual
    if X is None or ar is None:
        X, ar = np.zeros((n_rows, 0)), np.array([1.0])
    pieces = _pieces(prep, levels)
    p, K = X.shape[1], len(levels)
    m = keep.astype(float)
    Xw = (lfilter(ar, [1.0], X, axis=0) if p else X) * m[:, None]
    # whitening runs len(ar) - 1 rows past a piece's end (its filter's memory)
    spill = len(ar) - 1
    wpieces = []
    for j, r0, c in pieces:
        r1 = min(n_rows, r0 + len(c) + spill)
        cz = np.zeros(r1 - r0)
        cz[: len(c)] = c[: r1 - r0]
        wpieces.append((j, r0, lfilter(ar, [1.0], cz) * m[r0:r1]))

    def at(v: np.ndarray) -> np.ndarray:
        """[X, C]ᵀ of the whitened, kept rows v."""
        out = np.zeros(p + K)
        out[:p] = Xw.T @ v
        for j, r0, w in wpieces:
            out[p + j] += w @ v[r0 : r0 + len(w)]
        return out

    def fitted(theta: np.ndarray) -> np.ndarray:
        f = X @ theta[:p]
        for j, r0, c in pieces:
            f[r0 : r0 + len(c)] += theta[p + j] * c
        return f

    G = np.zeros((p + K, p + K))
    G[:p, :p] = Xw.T @ Xw
    order = sorted(range(len(wpieces)), key=lambda i: wpieces[i][1])
    for a_, i in enumerate(order):
        j, r0, w = wpieces[i]
        G[:p, p + j] += Xw[r0 : r0 + len(w)].T @ w
        G[p + j, p + j] += w @ w
        for k_ in order[a_ + 1 :]:  # the pieces that overlap this one (sorted by start)
            jk, s0, wk = wpieces[k_]
            if s0 >= r0 + len(w):
                break
            e = min(r0 + len(w), s0 + len(wk))
            v = float(w[s0 - r0 : e - r0] @ wk[: e - s0])
            G[p + j, p + jk] += v
            G[p + jk, p + j] += v
    G[p:, :p] = G[:p, p:].T
    solve = _solver(G)
    y = residual
    theta = solve(at(lfilter(ar, [1.0], y) * m))
    out = y - fitted(theta)
    # refinement: the normal equations square the design's condition number (the levels'
    # indicators nearly sum to the model's constant column); each step gains that much again
    for _ in range(REFINE):
        out = out - fitted(solve(at(lfilter(ar, [1.0], out) * m)))
    return np.asarray(np.where(keep, out, residual))


def _solver(G: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Least squares' minimum-norm solve of the normal equations G θ = g (columns equilibrated):
    directions of [X, C] whose singular value is under RANK_TOL of the largest are dropped, as
    lstsq drops a dependent column — the levels' indicators sum to the model's constant column
    where every sample is held."""
    d = np.sqrt(np.clip(np.diag(G), 0.0, None))
    d[d == 0] = np.inf
    lam, V = np.linalg.eigh(G / d[:, None] / d[None, :])
    good = lam > RANK_TOL**2 * max(float(lam.max()), 1e-300)
    V, inv = V[:, good], 1.0 / lam[good]

    def solve(g: np.ndarray) -> np.ndarray:
        return np.asarray((V @ (inv * (V.T @ (g / d)))) / d)

    return solve
