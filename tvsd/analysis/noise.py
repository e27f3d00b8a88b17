"""The residual's noise: whiteness, colour, and the vibration level.

The inverse model's residual in effort units holds J·Δv (the vibration) and the differentiated
speed-measurement noise. The paper's Δv (eq. 12) is white: a flat spectrum in the band. A
low-pass correlated Δv (Ornstein–Uhlenbeck, correlation time τ) is flat only below 1/(2πτ).
The test fits both spectral shapes to the residual's Welch spectrum by Whittle's likelihood and
compares them with a likelihood ratio (χ² with one degree of freedom: the extra τ):
    white:    S(f) = G(f)·(a·A(f) + b·f²)
    coloured: S(f) = G(f)·(a·A(f) / (1 + (2πfτ)²) + b·f²)
G is what the doctor's own processing does to the residual (tvsd.analysis.prep: the band filter
and the decimation's anti-alias filter, each run forwards and backwards, and the central
difference that makes the acceleration from the measured speed); A is the speed sample's mean
over its period (the vibration is motion, the measurement noise is not). With G known the test
uses the band up to BAND_SHARE of the corner instead of the half where the filter is flat: a
correlation time of 5 ms has its corner at 32 Hz, which the flat half (≤ 50 Hz) barely shows.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize
from scipy.signal import freqz, welch
from scipy.stats import chi2

from tvsd.analysis.prep import Prepared, _antialias

SEGMENT_S = 4.0
FLAT_SHARE = 0.5  # without the processing's response: the band filter is flat to 1 % up to half its corner
BAND_SHARE = 0.9  # with it: up to 90 % of the corner (the anti-alias filter: flat to 0.8 × Nyquist)

# f → (G(f), A(f)) of the module docstring
Response = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def processing_response(prep: Prepared) -> Response | None:
    """G and A of the residual's spectrum for this recording's processing, or None when the
    acceleration is not the central difference of a measured speed (EMPS: from the position)."""
    d = prep.data
    if d.speed is None:
        return None
    fs = d.sample_rate_hz
    b, a = prep.b, prep.a
    decim = prep.band.decim

    def response(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        g = np.abs(freqz(b, a, worN=f, fs=fs)[1]) ** 4
        if decim > 1:
            ba, aa = _antialias(decim)
            g = g * np.abs(freqz(ba, aa, worN=f, fs=fs)[1]) ** 4
        x = 2 * math.pi * f / fs
        g = g * np.sinc(x / math.pi) ** 2  # central difference: sin(x)/x in amplitude
        return g, np.sinc(f / fs) ** 2  # A: the period mean of the motion

    return response


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


def ljung_box(x: np.ndarray, lags: int = 20) -> float:
    x = x - x.mean()
    n = len(x)
    denom = float(x @ x)
    q = 0.0
    for k in range(1, lags + 1):
        rho = float(x[:-k] @ x[k:]) / denom
        q += rho * rho / (n - k)
    return float(chi2.sf(n * (n + 2) * q, lags))


def _whittle(
    params: np.ndarray, f: np.ndarray, p: np.ndarray, coloured: bool, g: np.ndarray, av: np.ndarray
) -> float:
    if np.any(np.abs(params) > 300):  # exp would overflow: outside any physical spectrum
        return math.inf
    a, b = math.exp(params[0]), math.exp(params[1])
    shape = 1 / (1 + (2 * math.pi * f * math.exp(params[2])) ** 2) if coloured else 1.0
    s = g * (a * shape * av + b * f**2)
    return float(np.sum(np.log(s) + p / s))


def _whittle_peak(params: np.ndarray, f: np.ndarray, p: np.ndarray, g: np.ndarray, av: np.ndarray) -> float:
    if np.any(np.abs(params) > 300):  # exp would overflow: outside any physical spectrum
        return math.inf
    a, b, A, f0, q = (math.exp(x) for x in params)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        s = g * ((a + A / (1 + q**2 * (f / f0 - f0 / f) ** 2)) * av + b * f**2)
        value = float(np.sum(np.log(s) + p / s))
    return value if math.isfinite(value) else math.inf


def _peak(
    fm: np.ndarray, pm: np.ndarray, a0: float, b0: float, g: np.ndarray, av: np.ndarray
) -> tuple[float, float, float, float]:
    """Whittle fit of a flat + f² floor with one resonant (Lorentzian) peak: (fun, f0, Q, power)."""
    floor = g * (a0 * av + b0 * fm**2)
    k = int(np.argmax(pm / floor))
    best = None
    for q0 in (3.0, 10.0, 30.0):
        start = [
            math.log(a0),
            math.log(b0),
            math.log(max(pm[k] - floor[k], 1e-3 * floor[k])),
            math.log(fm[k]),
            math.log(q0),
        ]
        r = minimize(
            _whittle_peak, start, args=(fm, pm, g, av), method="Nelder-Mead", options={"maxiter": 3000}
        )
        if best is None or r.fun < best.fun:
            best = r
    assert best is not None
    _, _, A, f0, q = (math.exp(x) for x in best.x)
    power = A * math.pi * f0 / (2 * q)  # ∫ of the Lorentzian over f (narrow-peak limit)
    return float(best.fun), f0, q, power


def analyse(
    residual: np.ndarray, rate_hz: float, J: float, band_hz: float, response: Response | None = None
) -> NoiseReport:
    nper = min(len(residual), int(SEGMENT_S * rate_hz))
    f, p = welch(residual - residual.mean(), fs=rate_hz, nperseg=nper)
    segments = max(1, 2 * len(residual) // nper - 1)  # 50 % overlap
    top = BAND_SHARE * band_hz if response is not None else FLAT_SHARE * band_hz
    m = (f >= 0.5) & (f <= min(top, 0.4 * rate_hz))
    fm, pm = f[m], p[m]
    g, av = response(fm) if response is not None else (np.ones_like(fm), np.ones_like(fm))
    a0 = max(float(np.median((pm / g)[: max(3, len(pm) // 10)])), 1e-30)
    b0 = max(float(np.median((pm / g)[-max(3, len(pm) // 10) :])) / fm[-1] ** 2, 1e-30)
    white = minimize(
        _whittle, [math.log(a0), math.log(b0)], args=(fm, pm, False, g, av), method="Nelder-Mead"
    )
    best = None
    for tau0 in (0.003, 0.01, 0.03, 0.1, 0.3):
        r = minimize(
            _whittle,
            [math.log(a0), math.log(b0), math.log(tau0)],
            args=(fm, pm, True, g, av),
            method="Nelder-Mead",
            options={"maxiter": 2000},
        )
        if best is None or r.fun < best.fun:
            best = r
    assert best is not None
    lr = max(0.0, 2 * segments * (white.fun - best.fun))
    tau = math.exp(best.x[2])
    # White Δv of intensity σv (eq. 12): one-sided PSD of J·Δv is 2·J²·σv².
    sigma_v = math.sqrt(math.exp(white.x[0]) / 2) / J if J > 0 else math.nan
    fun_peak, f0, q, power = _peak(fm, pm, a0, b0, g, av)
    peak_lr = max(0.0, 2 * segments * (best.fun - fun_peak))
    return NoiseReport(
        ljung_box(residual),
        lr,
        float(chi2.sf(lr, 1)),
        tau,
        sigma_v,
        f,
        p,
        peak_lr,
        f0,
        q,
        math.sqrt(max(power, 0.0)),
    )
