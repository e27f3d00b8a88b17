"""The decision rule: one likelihood ratio per cause, its false-alarm rate set by a parametric bootstrap.

1. Noise model. The baseline's residual rows are not white (the differentiated speed noise rises
   with frequency; a coloured vibration falls). An AR(p) model of that residual whitens every
   column alike (generalised least squares, tvsd.analysis.gls), so the Gaussian likelihood of the
   rows is honest.
2. Statistic. Each cause c adds a block W (for each value of its scanned parameter). With Q₀ an
   orthonormal basis of the whitened baseline and e₀ its residual, the block explains
   ΔRSS = |Q_cᵀe₀|², Q_c an orthonormal basis of W with the baseline projected out; the
   likelihood ratio is T = n·ln(RSS₀/(RSS₀ − ΔRSS)), maximised over the scanned values. A line
   fixed in Hz (resonance) is scanned over every frequency of the band through the periodogram
   (tvsd.analysis.linescan).
3. Calibration. Under the fitted baseline with its noise the whitened errors are Gaussian, so
   the same statistics computed for B draws of such errors (one matrix product for all blocks)
   give each cause's null distribution: with its own scan, its own size. The draws' noise has
   the whitened residual's own spectrum where it is above the flat level (null_gram; corrected
   for the baseline's leverage, floored at the flat level): AR(6) on the 250 Hz rows leaves
   its lowest hertz ≈ 1.2× too strong, where the columns of slow motion (friction, drift,
   imbalance, cogging) live, and an i.i.d. null put 16–17 % of the cogging and drift statistics
   of 300 open-loop nulls above their null's 90 % point. Each cause's statistic is standardised
   by its null (median and spread), the largest standardised statistic is the test (the max
   over causes, options and bins is what the draws reproduce: the multiplicity is in the null),
   and its threshold is the empirical (1 − α) point of B = 2000 draws of that maximum — the
   level is α, set, not tuned. (A Gumbel law fitted to 400 maxima by moments put the threshold
   0.1 low: 1.2 % for a nominal 1 %, measured on 8000 draws.) The bootstrap conditions on the
   regressors, as least squares does; what it does not cover is a baseline that is wrong in a
   way no cause describes (misfit; docs/measurements/doctor-false-alarms.md, "False alarms") — and in closed
   loop the command answers the noise, so the command-side blocks are not independent of it.
4. Out-of-sample confirmation of the winner (tvsd.analysis.crossval, applied by
   tvsd.analysis.verdict): fitted on four of five contiguous folds, the extension must predict the
   fifth better than the baseline.
   (A wild block bootstrap of the residual rows was tried as the null: it calibrated the resonance
   scan better but named friction asymmetry on a default-plant multisine null;
   docs/measurements/doctor-false-alarms.md.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tvsd.analysis import level_nuisance
from tvsd.analysis.design import Design, Option
from tvsd.analysis.gls import ar_filter, clear_memory, orth, whiten
from tvsd.analysis.linescan import RES_BAND, block_floor, excitation_rows, line_scan, refine_frequency

AR_ORDER = 6
BOOTSTRAP = 2000  # null draws: the threshold is their empirical (1 − α) point (± 0.2 % in level)
ALPHA = 0.01  # false-alarm rate of the whole decision (target ≤ 2 %)
LEVERAGE_FLOOR = 0.05  # a bin the baseline takes ≥ 95 % of is not read for the noise level
SPECTRUM_BINS = 21  # the null's noise spectrum: medians of blocks this many DFT bins wide

__all__ = ["Outcome", "Tested", "null_gram", "residual_spectrum", "test_all"]


@dataclass(frozen=True)
class Tested:
    cause: str
    option: Option | None  # None for resonance (see frequency)
    T: float  # likelihood ratio (max over the scan)
    z: float  # standardised by the cause's own null
    p: float  # bootstrap p-value of this cause alone
    frequency_hz: float = math.nan
    coef: np.ndarray | None = None


@dataclass(frozen=True)
class Outcome:
    tested: list[Tested]  # best first
    threshold: float  # standardised-statistic threshold at α
    n: int
    ar: np.ndarray  # whitening filter [1, −φ₁, …]
    significant: bool
    resid: np.ndarray  # whitened baseline residual
    keep: np.ndarray  # rows used after whitening


def _lr(n: int, rss0: np.ndarray | float, drss: np.ndarray | float) -> np.ndarray:
    return n * np.log(rss0 / np.maximum(np.asarray(rss0) - drss, 1e-300 * np.asarray(rss0)))


def test_all(design: Design, seed: int = 0, boot: int = BOOTSTRAP, alpha: float = ALPHA) -> Outcome:
    m = design.rows_mask
    # Baseline LS on the moving rows, then the AR noise model of its residual.
    theta, *_ = np.linalg.lstsq(design.X[m], design.y[m], rcond=None)
    r = np.where(m, design.y - design.X @ theta, 0.0)
    a = ar_filter(r[m], AR_ORDER)
    # Rows used: moving, and the filter's memory holds no stuck row.
    keep = clear_memory(m, len(a) - 1)
    y = whiten(design.y, a, keep)
    X = whiten(design.X, a, keep)
    n = len(y)
    Q0, _ = np.linalg.qr(X)
    e0 = y - Q0 @ (Q0.T @ y)
    rss0 = float(e0 @ e0)
    # A per-level error of the drive (tvsd.analysis.level_nuisance): a random effect of the null.
    lev = None
    if design.levels is not None:
        beta = np.linalg.lstsq(X, y, rcond=None)[0]  # the input gain: a₀ + a₁ (design.build's first two)
        lev = level_nuisance.null_term(design.levels, float(beta[0] + beta[1]), a, keep, Q0, e0, X.shape[1])
    on_levels: list[np.ndarray] = []  # each block's projection of the levels' indicators
    tested: list[Tested] = []
    blocks: list[tuple[int, int]] = []  # each option's columns in the stacked basis G
    owner: list[int] = []  # which tested cause each block belongs to
    G_parts: list[np.ndarray] = []
    col = 0
    for cause, options in design.options.items():
        T_best, opt_best, coef_best = -math.inf, None, None
        first = len(G_parts)
        for opt in options:
            Wq, Wr = orth(whiten(opt.block, a, keep), Q0)
            if Wq.shape[1] == 0:
                continue
            G_parts.append(Wq)
            if lev is not None:  # the levels' scatter this block's null carries (with it fitted)
                on_levels.append(math.sqrt(lev.ratio_with(Wq, e0)) * (Wq.T @ lev.Cr))
            blocks.append((col, col + Wq.shape[1]))
            col += Wq.shape[1]
            owner.append(len(tested))
            proj = Wq.T @ e0
            T = float(_lr(n, rss0, float(proj @ proj)))
            coef = np.linalg.lstsq(Wr, e0, rcond=None)[0]  # Frisch–Waugh: the block's coefficients
            if _sign_ok(opt, coef) and T_best < T:
                T_best, opt_best, coef_best = T, opt, coef
        if len(G_parts) == first:
            continue
        tested.append(Tested(cause, opt_best, max(T_best, 0.0), 0.0, 1.0, coef=coef_best))
    # Under the null the whitened errors are i.i.d. N(0, 1), so the projections Gᵀe of all the
    # blocks at once are N(0, GᵀG): drawn directly, B draws cost nothing next to the rows.
    rng = np.random.default_rng(seed)
    gram = null_gram(G_parts, e0, basis=Q0)  # takes the blocks (not a stacked copy) and empties the list
    if on_levels:
        M = np.vstack(on_levels)
        gram += M @ M.T
    vals, vecs = np.linalg.eigh(gram)
    root = vecs * np.sqrt(np.clip(vals, 0.0, None))
    P = root @ rng.standard_normal((gram.shape[0], boot))
    rss0_b = rng.chisquare(max(n - X.shape[1], 1), boot)
    null = [np.full(boot, -math.inf) for _ in tested]
    for (lo, hi), who in zip(blocks, owner, strict=True):
        drss = np.einsum("ij,ij->j", P[lo:hi], P[lo:hi])
        null[who] = np.maximum(null[who], _lr(n, rss0_b, drss))
    # Resonance: a sinusoid at any Fourier frequency of the band, through the periodogram; under
    # the null each of the N_f ordinates 2|F|²/n of white noise is χ²₂, independently.
    fs_rows = 1.0 / float(np.median(np.diff(design.prep.t_rows)))
    f_hi = RES_BAND * min(design.prep.band.cutoff_hz, fs_rows / 2)
    scan = line_scan(
        e0, [x[keep] for x in excitation_rows(design)], fs_rows, f_hi, design.prep.data.excitation_hz
    )
    drss_res, f0 = scan.peak(e0)
    f_ref = refine_frequency(design, f0, a, keep, Q0, e0)
    tested.append(Tested("resonance", None, float(_lr(n, rss0, drss_res)), 0.0, 1.0, frequency_hz=f_ref))
    null.append(_lr(n, rss0_b, scan.null_peaks(rng, boot)))

    # Standardise each cause by its own null; the max over causes is the test.
    Z_null = np.full(boot, -math.inf)
    out: list[Tested] = []
    for t, tn in zip(tested, null, strict=True):
        med = float(np.median(tn))
        spread = max(float(np.quantile(tn, 0.9)) - med, 1e-12)
        zn = (tn - med) / spread
        Z_null = np.maximum(Z_null, zn)
        z = (t.T - med) / spread
        p = (1 + int(np.count_nonzero(tn >= t.T))) / (boot + 1)
        out.append(Tested(t.cause, t.option, t.T, z, p, t.frequency_hz, t.coef))
    threshold = float(np.quantile(Z_null, 1 - alpha))
    out.sort(key=lambda s: -s.z)
    return Outcome(out, threshold, n, a, bool(out and out[0].z > threshold), e0, keep)


def residual_spectrum(
    e: np.ndarray, width: int = SPECTRUM_BINS, basis: np.ndarray | None = None
) -> np.ndarray:
    """The noise spectrum behind the whitened residual e, on the rfft grid of len(e), as a share of
    its mean level (1 where the AR whitening left it flat): each ordinate the median of its block
    of `width` bins over ln 2 (a median, so that a line — a cause — does not raise the level),
    and never below 1, the AR model's own level: a block median cannot resolve the lowest bins
    (0.7 Hz wide at 30 s, where a staircase's slow blocks put all their power), and read below
    the flat level it narrowed those blocks' nulls — on 6 open-loop nulls of seed 31 it named a
    dead zone, a clip and a friction asymmetry (z 3.0–3.3 under the flat null, 4.0–6.3 under
    it). Floored, the null is the AR model's where the residual shows less and wider where it
    shows more: conservative (a white residual's broadband blocks ≈ 10 % wider).

    e is the noise with the baseline's fit taken out: where the baseline's columns (`basis`,
    orthonormal) have their power, its periodogram is short by their leverage, E|ê_k|² =
    S_k·(1 − h_k) with h_k = Σ_j |F q_j|²_k / n — on a staircase the baseline's dozen columns sit
    in the lowest bins, and without this the slow blocks' null came out up to 2× narrow (a dead
    zone at z 3.0 under the white null, 5.95 under the uncorrected spectrum, on a null).

    The AR(AR_ORDER) filter on the 250 Hz rows whitens the band's high part, where most rows'
    power is, but not its lowest hertz: on 300 open-loop nulls (matrix seed 21) the whitened
    residual's periodogram over 1–5 Hz was 1.23× its mean (median; 5–95 % 1.07–1.39), where the
    friction, drift, imbalance and cogging columns of slow motion live."""
    n = len(e)
    if n < 2 * width:
        return np.ones(n // 2 + 1)
    pgram = np.abs(np.fft.rfft(e - e.mean())) ** 2
    if basis is not None and basis.shape[1]:
        h = np.sum(np.abs(np.fft.rfft(basis, axis=0)) ** 2, axis=1) / n
        pgram = pgram / np.clip(1.0 - h, LEVERAGE_FLOOR, 1.0)
    level = block_floor(pgram, width)
    return np.maximum(level / max(float(np.mean(level[1:])), 1e-300), 1.0)


def null_gram(
    G: np.ndarray | list[np.ndarray],
    e: np.ndarray,
    width: int = SPECTRUM_BINS,
    basis: np.ndarray | None = None,
) -> np.ndarray:
    """The covariance of Gᵀε for ε Gaussian, stationary, with the whitened residual e's spectrum
    (residual_spectrum): the bootstrap's noise model. For S ≡ 1 it is GᵀG (Parseval), the i.i.d.
    null; in general Σ_k S_k·Re(Ĝ_kᴴĜ_k)/n over the DFT of G's columns (circulant
    approximation: edge terms of order columns/rows).

    G may be a list of column blocks: each is transformed on its own (a column's DFT does not
    depend on its neighbours) and dropped from the list once transformed, and the weighted
    conjugate is made in place, so the peak is two DFT-sized arrays, not G stacked, its DFT, the
    weighted DFT and that one's conjugate (5 copies: 345 MB of a 120 s, 2 kHz analysis)."""
    blocks = G if isinstance(G, list) else [G]
    n = blocks[0].shape[0]
    S = residual_spectrum(e, width, basis)
    parts = []
    while blocks:
        parts.append(np.fft.rfft(blocks.pop(0), axis=0))
    F = parts[0] if len(parts) == 1 else np.column_stack(parts)
    parts.clear()
    w = np.full(F.shape[0], 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    Fc = np.conj(F)  # conj(F)·d for a real d is conj(F·d), value for value
    Fc *= (w * S)[:, None]
    return np.real(Fc.T @ F) / n


def _sign_ok(opt: Option, coef: np.ndarray) -> bool:
    return all(s == 0 or s * c > 0 for s, c in zip(opt.sign, coef, strict=False))
