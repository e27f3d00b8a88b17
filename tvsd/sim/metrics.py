"""Figures of merit of simulated (and measured) runs."""

from __future__ import annotations

import math

import numpy as np


def settling_time(t: np.ndarray, x: np.ndarray, ref: float, band: float = 0.02) -> float:
    """First time after which |x − ref| stays within band·|ref| (2 % band, as Table 6).

    Resolution is one sample; NaN when the run ends outside the band.
    """
    outside = np.nonzero(np.abs(x - ref) > band * abs(ref))[0]
    if len(outside) == 0:
        return float(t[0])
    last = outside[-1]
    return float(t[last + 1]) if last + 1 < len(t) else math.nan


def overshoot_pct(x: np.ndarray, ref: float, start: float = 0.0) -> float:
    """Largest excursion beyond the reference, in % of the step size (0 when none)."""
    step = ref - start
    if step == 0:
        return 0.0
    beyond = (x - ref) / step
    return float(max(0.0, 100.0 * beyond.max()))


def dominant_frequency(
    signal: np.ndarray, rate_hz: float, min_hz: float = 1.0, resolution_hz: float = 0.25
) -> tuple[float, float]:
    """Strongest spectral line (Welch, Hann): (frequency Hz, amplitude of the line).

    Segments are 1/resolution_hz long (fewer if the signal is short); the amplitude is that of a
    sinusoid with the peak's power, so a pure A·sin gives A. Lines below min_hz are ignored.
    """
    from scipy.signal import welch

    x = np.asarray(signal, dtype=float) - float(np.mean(signal))
    nper = min(len(x), round(rate_hz / resolution_hz))
    f, pxx = welch(x, fs=rate_hz, window="hann", nperseg=nper, scaling="spectrum")
    mask = f >= min_hz
    if not np.any(mask):
        return math.nan, math.nan
    i = int(np.argmax(np.where(mask, pxx, -np.inf)))
    # Refine the peak with a parabola through the log power of the three bins around it.
    freq = float(f[i])
    if 0 < i < len(f) - 1 and np.all(pxx[i - 1 : i + 2] > 0):
        a, b, c = np.log(pxx[i - 1 : i + 2])
        denom = a - 2 * b + c
        if denom < 0:
            freq += 0.5 * (a - c) / denom * float(f[1] - f[0])
    # A Hann window spreads a line over ~1.5 bins: sum the neighbours for the line's power.
    power = float(np.sum(pxx[max(i - 1, 0) : i + 2]))
    return freq, math.sqrt(2.0 * power / 1.5)
