"""The residual's noise: whiteness, colour, and the vibration level.

The inverse model's residual in effort units holds J·Δv (the vibration) and the differentiated
speed-measurement noise. The paper's Δv (eq. 12) is white: a flat spectrum in the band. A
low-pass correlated Δv (Ornstein–Uhlenbeck, correlation time τ) is flat only below 1/(2πτ).
The test fits both spectral shapes to the residual's Welch spectrum by Whittle's likelihood and
compares them with a likelihood ratio (χ² with one degree of freedom: the extra τ):
    white:    S(f) = a + b·f² + F(f)
    coloured: S(f) = a / (1 + (2πfτ)²) + b·f² + F(f)
An encoder's quantisation (white in φ: f⁴ in the residual once the speed is the position's
difference) is in both shapes as a known floor F(f) (tvsd.analysis.quantisation: its level from
the count step and the recorded speed, no free parameter; zero when ω is not a count
difference). A fitted f⁴ term made the outsider's encoder nulls flat but also bent the flat
shape to tvsd's own 20 ms OU colour's roll-off (likelihood ratio 18.7 → 4.6, missed); a known
floor cannot bend (docs/measurements/quantfloor.md).
Both shapes are seen through the rows' filters' power response G(f) when the caller gives it
(tvsd.analysis.rowgain: the band filter, the acceleration's central difference, the decimation's
anti-alias): S(f) = G(f)·(raw shape) + F(f), F having G in it already. A white vibration reaches
the rows as G, 0.87 at the band's top at 500 Hz (the central difference's sinc²); a flat shape
without it read long white residuals as a low-pass (500 Hz, 600 s: 6/6 alarms,
docs/measurements/colourgain.md).
The Whittle sum treats every bin of every segment as independent; with a Hann window and 50 %
overlap they are not (neighbouring bins and overlapping segments share data), so the ratio is
scaled by the effective number of segments (`effective_segments`), not the count; and that number
is read on the rows' own levels (`rows_worth`): rows left out as zeros add segments that hold no
data (docs/measurements/colourseg.md).
The one-peak fit over the whole band (a structural mode) is tvsd.analysis.peak's; `spectrum_report`
runs both tests, `spectral_cause` judges the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import get_window, welch
from scipy.stats import chi2

from tvsd.analysis.peak import (
    PEAK_FLOOR_C,
    PEAK_Q,
    PEAK_WHITE_LR,
    fit_peak,
    fit_shapes,
    on_segments,
    seen_height,
    shape_fits,
    welch_layout,
)
from tvsd.analysis.prep import ANTIALIAS_CORNER
from tvsd.analysis.quantisation import Floor
from tvsd.analysis.rowgain import Gain, peak_top

COLOUR_P = 1e-3  # the noise colour's likelihood ratio (χ², 1 dof) must beat this p-value (the doctor's gate)
SEGMENT_S = 4.0
BAND_LOW_HZ = 0.5  # the spectral tests' lowest frequency
MIN_SEEN_BINS = 12  # 3 Hz of band above the quantisation's floor: fewer, and no shape is told


@dataclass(frozen=True)
class NoiseReport:
    ljung_box_p: float  # whiteness of the residual rows (20 lags)
    colour_lr: float  # likelihood ratio, coloured vs white spectrum
    colour_p: float
    tau_s: float  # fitted correlation time (coloured model)
    sigma_v: float  # vibration level, rad/s^1.5 (white) from the flat part of the spectrum
    freq: np.ndarray
    psd: np.ndarray
    peak_lr: float = 0.0  # a resonant peak against the low-pass shape (χ², 2 dof)
    peak_hz: float = math.nan
    peak_q: float = math.nan
    peak_rms: float = math.nan  # the peak's share of the residual, rms (residual units)
    peak_white_lr: float = 0.0  # the same peak against the flat floor alone (χ², 3 dof)
    peak_over_floor: float = math.inf  # the peak's height over the known quantisation floor at its centre
    colour_band_hz: tuple[float, float] | None = None  # the bins the colour test saw (None: not run)
    peak_band_hz: tuple[float, float] | None = None  # the bins the peak test saw (None: not run)
    floor_cut_hz: float | None = None  # where the quantisation floor passes the flat level (None: nowhere)


def spectral_cause(report: NoiseReport, p_value: float) -> str | None:
    """What the residual spectrum's shape names: 'resonance' for a peak with Q ≥ PEAK_Q, tested
    first and against the flat floor (a 44 Hz mode in a 0–50 Hz band need not look low-pass),
    and better than the low-pass shape; else 'colored_noise' when a low-pass beats flat at
    `p_value`; else None."""
    if (
        report.peak_q >= PEAK_Q
        and _flanked(report)
        and report.peak_white_lr > PEAK_WHITE_LR
        and report.peak_lr > chi2.isf(p_value, 2)
        and report.peak_over_floor >= PEAK_FLOOR_C
    ):
        return "resonance"
    if report.colour_p < p_value:
        return "colored_noise"
    return None


def _flanked(report: NoiseReport) -> bool:
    """Whether the peak has bins of the band on both sides: two bins inside the bottom of the
    bins the peak test saw, where a Lorentzian fits a low-frequency rise as well as a mode (an
    outsider null's 'mode' at 0.555 Hz, Q 8e5, in a band that starts at 0.5 Hz), and its centre
    no higher than their top, where an encoder's quantisation floor rises steeply (a gapped
    encoder null's 'mode' at 54.7 Hz, outside its 50 Hz band). Two bins inside the top as well
    held no null in 1213 and lost the 3 of 52 modes at 30–50 Hz that lay at 49.6–50 Hz
    (docs/measurements/peakfix.md)."""
    df = float(report.freq[1] - report.freq[0]) if len(report.freq) > 1 else 0.0
    low, high = report.peak_band_hz or (BAND_LOW_HZ, math.inf)
    return max(low, BAND_LOW_HZ) + 2 * df <= report.peak_hz <= high


def ljung_box(x: np.ndarray, lags: int = 20) -> float:
    x = x - x.mean()
    n = len(x)
    denom = float(x @ x)
    q = 0.0
    for k in range(1, lags + 1):
        rho = float(x[:-k] @ x[k:]) / denom
        q += rho * rho / (n - k)
    return float(chi2.sf(n * (n + 2) * q, lags))


def effective_segments(segments: int, nper: int) -> float:
    """The number of independent segments a Whittle sum over a Hann, 50 %-overlapped Welch
    spectrum of `segments` segments of `nper` samples is worth, for a smooth spectral shape.

    A smooth functional Σ g(f_k)·p_k of the spectrum is a weighted sum of the squared samples,
    each weighted by W(t) = Σ_segments w(t)² (its window in every segment it is in); its variance
    is ∝ Σ W(t)², where independent bins and segments would give K·(Σ w²)²/nper. The ratio
    c = nper·Σ W² / (K·(Σ w²)²) is 35/18 ≈ 1.94 for one Hann segment (bin correlations 4/9 and
    1/36 at one and two bins) and → 19/9 ≈ 2.11 for many 50 %-overlapped ones (2.10 at K = 14,
    the doctor's 30 s); the likelihood ratio is χ² with the sum scaled by K/c."""
    k = max(1, int(segments))
    w2 = get_window("hann", nper) ** 2
    step = nper - nper // 2
    W = np.zeros((k - 1) * step + nper)
    for i in range(k):
        W[i * step : i * step + nper] += w2
    return float(k * k * w2.sum() ** 2 / (nper * np.sum(W * W)))


def rows_worth(residual: np.ndarray, nper: int) -> float:
    """`effective_segments` on the rows' own levels: what a Whittle sum over the Welch spectrum of
    `residual` (Hann, 50 % overlap, `nper`) is worth when its rows differ in variance v(t) — rows
    left out as zeros where the shaft was stuck, a ramp at a gap, a staircase level noisier than
    another.

    The same smooth functional Σ W(t)·x(t)² has mean ∝ Σ W·v and variance ∝ Σ W²·v², so the
    count is (Σ W·v)² / (nper·Σ W²·v²): effective_segments when v is one level. Counted on K the
    ratio was inflated by the left-out share (a white residual with its first 20–50 % left out:
    `tests/test_colour_segments.py`); the segments' own levels (peak.segment_share's (Σl)²/Σl²)
    miss the overlap's share of the zero segments (o17001's ratio still fell 11.1 → 9.2 as
    its left-out rows were cut away: docs/measurements/colourseg.md). v is the rows' power
    averaged over a quarter segment: its sampling scatter (2/(nper/4): 0.4 % on 2000 rows)
    biases the count by that much, and a step in v is followed to within nper/8 rows."""
    x = np.asarray(residual, dtype=float)
    n = len(x)
    nper, step, k = welch_layout(n, nper)
    w2 = get_window("hann", nper) ** 2 if nper > 1 else np.ones(1)
    W = np.zeros(n)
    for i in range(k):
        W[i * step : i * step + nper] += w2
    m = max(1, nper // 4)
    box = np.ones(m)
    # the mean over the rows in the box: at the record's ends it holds fewer
    v = np.convolve((x - x.mean()) ** 2, box, mode="same") / np.convolve(np.ones(n), box, mode="same")
    total = float(np.sum((W * v) ** 2))
    if total <= 0:
        return effective_segments(k, nper)
    return float(np.sum(W * v) ** 2 / (nper * total))


def analyse(
    residual: np.ndarray,
    rate_hz: float,
    J: float,
    band_hz: float,
    floor: Floor | None = None,
    gain: Gain | None = None,
) -> NoiseReport:
    """The spectral tests on the residual rows; `floor`: the encoder quantisation's known PSD
    (tvsd.analysis.quantisation.floor), None when the speed is not a count difference; `gain`:
    the rows' filters' power response (tvsd.analysis.rowgain.rows_gain), through which both
    tests' shapes are seen and which takes the peak test to the band filter's corner (None: the
    shapes as they are, the peak test to half the corner, where the filter is flat)."""
    f, p, segments = _welch(residual, rate_hz)
    worth = rows_worth(residual, 2 * (len(f) - 1))
    return on_segments(
        spectrum_report(f, p, segments, J, band_hz, ljung_box(residual), floor, gain, worth), residual
    )


def colour_test(
    residual: np.ndarray,
    rate_hz: float,
    band_hz: float,
    floor: Floor | None = None,
    gain: Gain | None = None,
) -> tuple[float, float]:
    """The colour test alone (likelihood ratio, p-value; χ², 1 dof), without the peak's fits;
    through the rows' filters' `gain` when given (as `analyse`)."""
    f, p, _ = _welch(residual, rate_hz)
    fm, pm, known, a0, b0 = _in_band(f, p, band_hz, floor, gain)
    if len(fm) < MIN_SEEN_BINS:
        return 0.0, 1.0  # the band is the quantisation's: no colour can be told
    white, best = _colour_fits(fm, pm, known, a0, b0, _gain_on(gain, fm))
    lr = max(0.0, 2 * rows_worth(residual, 2 * (len(f) - 1)) * (white.fun - best.fun))
    return lr, float(chi2.sf(lr, 1))


def _welch(residual: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray, int]:
    nper = min(len(residual), int(SEGMENT_S * rate_hz))
    f, p = welch(residual - residual.mean(), fs=rate_hz, nperseg=nper)
    return f, p, max(1, 2 * len(residual) // nper - 1)  # 50 % overlap


def _whole_band(
    f: np.ndarray, p: np.ndarray, band_hz: float, floor: Floor | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """The band's bins, the known floor on them, a starting level for a (the floor taken off: it
    is not a's to fit), and the index of the first bin where the floor passes that flat level
    (the number of bins when it never does)."""
    m = (f >= BAND_LOW_HZ) & (f <= band_top(f, band_hz))
    fm, pm = f[m], p[m]
    known = np.zeros_like(fm) if floor is None else np.asarray(floor(fm), dtype=float)
    k = max(3, len(pm) // 10)
    a0 = max(float(np.median((pm - known)[:k])), 1e-3 * float(np.median(pm[:k])), 1e-300)
    above = np.nonzero(known > a0)[0]
    return fm, pm, known, a0, int(above[0]) if len(above) else len(fm)


def band_top(f: np.ndarray, band_hz: float) -> float:
    """The top of the band where the rows' filters are flat: half the band filter's corner (flat
    to 1 % there), and no higher than the decimation's anti-alias corner (ANTIALIAS_CORNER of the
    rows' Nyquist, f[-1]), which a file under 500 Hz puts below that half (100 Hz: the band's
    half at 20 Hz, the rows' Nyquist 12.5 Hz, the roll-off from 10 Hz fitted as a low-pass, a
    white residual's colour p 0; docs/measurements/review6.md). Without decimation the rows'
    Nyquist is the file's, above 0.5·band_hz ≤ 0.2·fs, and this cap never binds."""
    if not len(f):
        return 0.5 * band_hz
    # the rows' rate is read off their times (1/median Δt): at 500 Hz the corner, 50 Hz, is the
    # band's half to within rounding, and that rounding must not drop the 50 Hz bin
    return min(0.5 * band_hz, ANTIALIAS_CORNER * float(f[-1]) * (1 + 1e-9))


def _slope(fm: np.ndarray, pm: np.ndarray, known: np.ndarray, gain: np.ndarray | float = 1.0) -> float:
    """A starting level for b (the f² term) from the band's top tenth, the known floor taken off
    (and the filters' gain, before which b is)."""
    k = max(3, len(pm) // 10)
    return max(float(np.median(((pm - known) / gain)[-k:])) / fm[-1] ** 2, 1e-30)


def _gain_on(gain: Gain | None, fm: np.ndarray) -> np.ndarray | float:
    """The filters' power response on the bins `fm` (1.0 without it: the shapes as they are)."""
    return 1.0 if gain is None else np.asarray(gain(fm), dtype=float)


def _in_band(
    f: np.ndarray, p: np.ndarray, band_hz: float, floor: Floor | None = None, gain: Gain | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """The colour test's bins, the known floor on them, and starting levels for a and b. With a
    floor, the band ends where the floor first passes the flat level of the lowest bins: above,
    the residual is the quantisation's, whose line structure the floor places only to within its
    width (a staircase's lines at 1–2× the floor, tests/quantisation_nulls.py), and says nothing
    of the vibration's low-pass shape (docs/measurements/bandfloor.md: over the whole band the
    colour test's nulls and detections)."""
    fm, pm, known, a0, cut = _whole_band(f, p, band_hz, floor)
    fm, pm, known = fm[:cut], pm[:cut], known[:cut]
    if len(fm) < MIN_SEEN_BINS:
        return fm, pm, known, a0, 1e-30
    return fm, pm, known, a0, _slope(fm, pm, known, _gain_on(gain, fm))


def _colour_fits(
    fm: np.ndarray, pm: np.ndarray, known: np.ndarray, a0: float, b0: float, gain: np.ndarray | float = 1.0
) -> tuple[Any, Any]:
    """Whittle fits of the white and the coloured shape (scipy OptimizeResults) through the
    filters' `gain` on the bins: peak.shape_fits."""
    return shape_fits(fm, pm, known, gain, a0, b0)


def spectrum_report(
    f: np.ndarray,
    p: np.ndarray,
    segments: int,
    J: float,
    band_hz: float,
    lb_p: float = math.nan,
    floor: Floor | None = None,
    gain: Gain | None = None,
    worth: float | None = None,
) -> NoiseReport:
    """The spectral tests on a Welch spectrum (f, p) of `segments` segments (a stored spectrum
    can be re-judged without its residual); `worth`: what the colour's Whittle sum is worth in
    segments (`rows_worth` of the residual; None: `effective_segments` of the count, the rows'
    level taken as one). The colour test stops where the quantisation's floor
    passes the flat level (`_in_band`); the peak test runs over the whole band with the floor in
    its model (a peak must stand PEAK_FLOOR_C× above it: `spectral_cause`); with the filters'
    `gain`, over the band the filters pass (`_peak_fits`)."""
    fw, pw, kw, a0, cut = _whole_band(f, p, band_hz, floor)
    cut_hz = float(fw[cut]) if cut < len(fw) else None
    sigma0 = math.sqrt(a0 / 2) / J if J > 0 else math.nan
    if len(fw) < MIN_SEEN_BINS:  # no band to test
        return NoiseReport(lb_p, 0.0, 1.0, 0.0, sigma0, f, p, floor_cut_hz=cut_hz)
    lr, tau, sigma_v, colour_band = 0.0, 0.0, sigma0, None
    whole = None
    if cut >= MIN_SEEN_BINS:  # else the colour's band is the quantisation's: no colour is told
        fm, pm, known = fw[:cut], pw[:cut], kw[:cut]
        gm = _gain_on(gain, fm)  # both shapes as the rows' filters pass them: G·white is the null
        b0 = _slope(fm, pm, known, gm)
        white, best = _colour_fits(fm, pm, known, a0, b0, gm)
        # The colour's ratio on the effective segments (inflated ≈ 2.1× on the count: 11 of 300
        # open-loop nulls were false alarms, 6 of them colour, docs/measurements/doctor-false-alarms.md);
        # the peak's statistics keep the count: PEAK_WHITE_LR was calibrated on them.
        if worth is None:
            worth = effective_segments(segments, 2 * (len(f) - 1))
        lr = max(0.0, 2 * worth * (white.fun - best.fun))
        tau = math.exp(best.x[2])
        # White Δv of intensity σv (eq. 12): one-sided PSD of J·Δv is 2·J²·σv².
        sigma_v = math.sqrt(math.exp(white.x[0]) / 2) / J if J > 0 else math.nan
        colour_band = (float(fm[0]), float(fm[-1]))
        if cut == len(fw):  # no floor cut: the colour's fits are the peak's alternatives
            whole = (white, best, b0)
    if gain is not None:
        fw, (white_w, best_w, fun_peak, f0, q, power, seen) = _peak_fits(f, p, a0, floor, gain)
    else:
        if whole is None:  # the peak's alternatives over the whole band, the known floor in both
            b0w = _slope(fw, pw, kw)
            whole = (*_colour_fits(fw, pw, kw, a0, b0w), b0w)
        white_w, best_w, b0w = whole
        fun_peak, f0, q, power, height = fit_peak(fw, pw, a0, b0w, kw)
        seen = seen_height(fw, f0, q, height, 1.5 * float(f[1] - f[0]))
    over = math.inf if floor is None else seen / max(float(floor(np.array([f0]))[0]), 1e-300)
    return NoiseReport(
        lb_p,
        lr,
        float(chi2.sf(lr, 1)),
        tau,
        sigma_v,
        f,
        p,
        max(0.0, 2 * segments * (best_w.fun - fun_peak)),
        f0,
        q,
        math.sqrt(max(power, 0.0)),
        max(0.0, 2 * segments * (white_w.fun - fun_peak)),
        over,
        colour_band,
        (float(fw[0]), float(fw[-1])),
        cut_hz,
    )


def _peak_fits(
    f: np.ndarray, p: np.ndarray, a0: float, floor: Floor | None, gain: Gain
) -> tuple[np.ndarray, tuple[Any, Any, float, float, float, float, float]]:
    """The peak test's bins — up to where the filters' gain falls to rowgain.PEAK_GAIN_MIN — and
    its fits through the gain: the two alternatives, the peak (fun, f0, Q, power before the
    filters) and its height as the spectrum shows it (through the gain at f0)."""
    m = (f >= BAND_LOW_HZ) & (f <= peak_top(gain, f))
    fw, pw = f[m], p[m]
    gw = np.asarray(gain(fw), dtype=float)
    kw = np.zeros_like(fw) if floor is None else np.asarray(floor(fw), dtype=float)
    white, best, b0 = fit_shapes(fw, pw, kw, gw, a0)
    fun_peak, f0, q, power, height = fit_peak(fw, pw, a0, b0, kw, gw)
    seen = seen_height(fw, f0, q, height, 1.5 * float(f[1] - f[0])) * float(gain(np.array([f0]))[0])
    return fw, (white, best, fun_peak, f0, q, power, seen)
