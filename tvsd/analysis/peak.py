"""The residual spectrum's peak: one resonant (Lorentzian) peak against the flat floor.

The Whittle fit of a flat + f² (+ the encoder quantisation's known floor) spectrum with one
Lorentzian peak, its frequency scanned from the largest excesses over the floor (`fit_peak`); the
peak's height as the spectrum shows it (`seen_height`); whether it sits on a line the recording
declares (`on_declared_line`). The statistics are tvsd.analysis.noise.NoiseReport's peak_*
fields (noise.spectrum_report), the gate that names a resonance is noise.spectral_cause, with
the thresholds below. Split from noise.py (branch splits3), unchanged."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.optimize import minimize
from scipy.signal import get_window

if TYPE_CHECKING:  # noise.py imports this module: NoiseReport is only an annotation here
    from tvsd.analysis.noise import NoiseReport

PEAK_Q = 5.0  # a spectral peak this sharp is a structural mode; broader is a low-pass colour
# The peak against the flat floor (3 more parameters, its frequency scanned): the Whittle ratio
# on a 50 %-overlapped Welch spectrum is not χ²₃. Calibrated on 700 simulated null residuals
# (flat + differentiated measurement noise in any mix, at the doctor's 250 Hz rows; 400 of 30 s,
# 300 of 60 s; scripts/naming_peak_null.py): 99 % points 28.9 / 31.7, Gumbel 99.9 % points
# 41.4 / 43.4, largest 44.8 / 36.1 — none above 45.
PEAK_WHITE_LR = 45.0
# With an encoder's quantisation floor the peak is sought over the whole band, the floor in its
# model; the floor places the quantisation's lines only to within their width (1.2–2× in places on
# a staircase), so a peak must also stand this many times above the floor at its centre.
# Calibrated on randomised encoder nulls (docs/measurements/bandfloor.md).
PEAK_FLOOR_C = 5.0


def on_declared_line(report: NoiseReport, lines_hz: tuple[float, ...]) -> bool:
    """Whether an excitation line the recording declares (`# excitation_hz:`) lies in the spectral
    peak's half-power band, f/(2Q) each side (at least the spectrum's resolution): the rigid
    model's misfit of the response to that line makes such a peak (a closed-loop null's 7.91 Hz,
    Q 35, beside identify's 8 Hz line, seed 62), and a mode there cannot be told from it."""
    if not lines_hz or not math.isfinite(report.peak_hz):
        return False
    df = float(report.freq[1] - report.freq[0]) if len(report.freq) > 1 else 0.0
    half = max(report.peak_hz / (2.0 * report.peak_q), df) if report.peak_q > 0 else df
    return any(abs(report.peak_hz - f) <= half for f in lines_hz)


def _whittle_peak(
    params: np.ndarray, f: np.ndarray, p: np.ndarray, known: np.ndarray, gain: np.ndarray | float = 1.0
) -> float:
    if np.any(np.abs(params) > 300):  # exp would overflow: outside any physical spectrum
        return math.inf
    a, b, A, f0, q = (math.exp(x) for x in params)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        s = gain * (a + b * f**2 + A / (1 + q**2 * (f / f0 - f0 / f) ** 2)) + known
        value = float(np.sum(np.log(s) + p / s))
    return value if math.isfinite(value) else math.inf


def _lowest(fun: Any, points: list[list[float]], args: tuple[Any, ...], maxiter: int) -> Any:
    """Nelder–Mead from each start point; the result of least `fun` (the first on a tie)."""
    best = None
    for x0 in points:
        r = minimize(fun, x0, args=args, method="Nelder-Mead", options={"maxiter": maxiter})
        if best is None or r.fun < best.fun:
            best = r
    assert best is not None
    return best


def fit_peak(
    fm: np.ndarray,
    pm: np.ndarray,
    a0: float,
    b0: float,
    known: np.ndarray,
    gain: np.ndarray | float = 1.0,
) -> tuple[float, float, float, float, float]:
    """Whittle fit of a flat + f² floor with one resonant (Lorentzian) peak, all through the
    rows' filters' power response `gain` (tvsd.analysis.rowgain), plus the known quantisation:
    (fun, f0, Q, power, height at f0) of the peak before the filters."""
    gain = np.broadcast_to(np.asarray(gain, dtype=float), fm.shape)
    floor = gain * (a0 + b0 * fm**2) + known
    starts = [int(np.argmax(pm / floor))]
    if np.any(known > 0):  # over the floor a single bin's scatter is large: also the 5-bin excess
        starts.append(int(np.argmax(np.convolve(pm / floor, np.ones(5) / 5, mode="same"))))
    points = [
        [
            math.log(a0),
            math.log(b0),
            math.log(max(pm[k] - floor[k], 1e-3 * floor[k]) / gain[k]),
            math.log(fm[k]),
            math.log(q0),
        ]
        for k in dict.fromkeys(starts)
        for q0 in (3.0, 10.0, 30.0)
    ]
    best = _lowest(_whittle_peak, points, (fm, pm, known, gain), 3000)
    _, _, A, f0, q = (math.exp(x) for x in best.x)
    power = A * math.pi * f0 / (2 * q)  # ∫ of the Lorentzian over f (narrow-peak limit)
    return float(best.fun), f0, q, power, A


def _whittle_shape(
    params: np.ndarray, f: np.ndarray, p: np.ndarray, known: np.ndarray, gain: np.ndarray | float
) -> float:
    """Whittle's negative log-likelihood of the flat + f² (+ a low-pass with a third parameter,
    τ = e^params[2]) shape through `gain`, plus the known floor."""
    if np.any(np.abs(params) > 300):  # exp would overflow: outside any physical spectrum
        return math.inf
    a, b = math.exp(params[0]), math.exp(params[1])
    lowpass = 1.0 if len(params) < 3 else 1 + (2 * math.pi * f * math.exp(params[2])) ** 2
    s = gain * (a / lowpass + b * f**2) + known
    return float(np.sum(np.log(s) + p / s))


def fit_shapes(
    fm: np.ndarray, pm: np.ndarray, known: np.ndarray, gain: np.ndarray, a0: float
) -> tuple[Any, Any, float]:
    """The peak's alternatives through the rows' filters (the white and the low-pass shape,
    `shape_fits`), and the f² term's start."""
    k = max(3, len(pm) // 10)
    b0 = max(float(np.median(((pm - known) / gain)[-k:])) / fm[-1] ** 2, 1e-30)
    return (*shape_fits(fm, pm, known, gain, a0, b0), b0)


def shape_fits(
    fm: np.ndarray, pm: np.ndarray, known: np.ndarray, gain: np.ndarray | float, a0: float, b0: float
) -> tuple[Any, Any]:
    """Whittle fits of the white (flat + f²) and the low-pass shape through `gain` (the rows'
    filters' power response, tvsd.analysis.rowgain: the peak test's and, since colourgain, the
    colour test's, tvsd.analysis.noise) plus the known floor, from the levels a0, b0 (scipy
    OptimizeResults)."""
    white = minimize(
        _whittle_shape, [math.log(a0), math.log(b0)], args=(fm, pm, known, gain), method="Nelder-Mead"
    )
    points = [[math.log(a0), math.log(b0), math.log(tau0)] for tau0 in (0.003, 0.01, 0.03, 0.1, 0.3)]
    return white, _lowest(_whittle_shape, points, (fm, pm, known, gain), 2000)


def seen_height(fw: np.ndarray, f0: float, q: float, height: float, enbw: float) -> float:
    """The fitted peak's height as the spectrum shows it: its Lorentzian's largest value on the
    band's bins, and no more than its power spread over the Hann window's noise bandwidth `enbw`
    (a line narrower than that is spread over it, however large the fitted top). The first
    bound holds a fit far narrower than a bin, which models the excess of the bins beside f0
    with its tails (A/Q² fixed, A/Q free): a staircase null's line 3.8× the floor on its bins
    was fitted at Q 1.5e8, and its power over 1.5 bins read 2.5e6× the floor (seed 1201,
    docs/measurements/peakevid.md)."""
    if q <= 0:
        return height
    on_bins = float(np.max(height / (1.0 + (q * (fw / f0 - f0 / fw)) ** 2)))
    return min(on_bins, height * min(1.0, math.pi * f0 / (2 * q) / enbw))


def welch_layout(n: int, nper: int) -> tuple[int, int, int]:
    """scipy's welch segments of `n` rows (Hann, 50 % overlap): the segment length (at most n),
    the step between starts and the count."""
    nper = max(1, min(int(nper), n))
    step = nper - nper // 2
    return nper, step, max(1, (n - nper) // step + 1)


def segment_share(residual: np.ndarray, nper: int) -> float:
    """(Σ l_k)² / (K·Σ l_k²) over the K Welch segments (Hann, 50 % overlap, `nper` samples, each
    less its mean: scipy's welch) of the residual rows, l_k each segment's windowed power.

    The Whittle ratio on a Welch average treats the K segments as K equal draws of one spectrum:
    the average's relative variance 1/K. Segments of unequal level l_k (rows left out as zeros
    where the shaft was stuck, a staircase level whose noise is larger than another's) average to
    a relative variance Σl²/(Σl)² — the same as (Σl)²/Σl² equal segments — so the ratio counted
    on K is that much too large: a white residual with its first 40 % left out read twice the
    peak ratio of the whole record (median 17.4 against 9.5, 2 of 100 above PEAK_WHITE_LR,
    docs/measurements/res17.md). 1 for equal levels, to within the levels' own sampling scatter
    (≈ 4/nper: 0.4 % on white noise in 1000-row segments); a stationary narrow mode's own
    segment-to-segment scatter lowers it too (0.6–0.94 on pure modes of Q 200–5, 0.99 with the
    mode at 0.3 of the noise: the review in docs/measurements/session8.md)."""
    nper, step, k = welch_layout(len(residual), nper)
    window = get_window("hann", nper) if nper > 1 else np.ones(1)
    levels = np.empty(k)
    for i in range(k):
        seg = residual[i * step : i * step + nper]
        levels[i] = float(np.sum((window * (seg - seg.mean())) ** 2))
    total = float(np.sum(levels * levels))
    return float(np.sum(levels) ** 2 / (k * total)) if total > 0 else 1.0


def on_segments(report: NoiseReport, residual: np.ndarray) -> NoiseReport:
    """The report with the peak's two likelihood ratios counted on the segments' equal-level
    equivalent (`segment_share`): PEAK_WHITE_LR was calibrated on stationary residuals, where
    the share is 1 and nothing changes."""
    if len(report.freq) < 2:
        return report
    share = segment_share(residual, 2 * (len(report.freq) - 1))
    return dataclasses.replace(
        report, peak_lr=report.peak_lr * share, peak_white_lr=report.peak_white_lr * share
    )
