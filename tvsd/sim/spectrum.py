"""Vibration spectra as Welch estimates with a noise floor and a line test (plots and `sim spin`).

A raw periodogram's bins scatter by ±100 % (χ² with 2 degrees of freedom), so a line barely clears
them and the strongest bin of pure noise lands anywhere (the issue's "dominant 397 Hz"). Averaging
K segments (Welch, Hann) makes each bin χ² with ≈ 2K degrees of freedom; the floor is the running
median of the bins (robust to the lines themselves), and a line counts when its bin exceeds the
floor by the χ² quantile that pure noise would pass in 1 % of runs over all bins (Bonferroni).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FALSE_ALARM = 0.01  # per spectrum, over all its bins
FLOOR_HALF_WIDTH_HZ = 10.0  # the running median's half width


@dataclass(frozen=True)
class Spectrum:
    f: np.ndarray  # Hz
    psd: np.ndarray  # (rad/s²)²/Hz, one-sided
    floor: np.ndarray  # the noise level under each bin (running median, bias-corrected)
    threshold: float  # psd / floor above which a bin is a line (1 % false alarms per spectrum)
    segments: int  # independent segments averaged
    peak_hz: float  # the strongest bin above min_hz
    peak_ratio: float  # its psd / floor
    significant: bool  # peak_ratio > threshold

    @property
    def resolution_hz(self) -> float:
        return float(self.f[1] - self.f[0])

    def ratio_at(self, hz: float) -> float:
        """psd / floor of the bin holding hz (the best of it and its two neighbours: a line
        between bins spreads over two)."""
        i = int(np.argmin(np.abs(self.f - hz)))
        sl = slice(max(i - 1, 0), i + 2)
        return float(np.max(self.psd[sl] / np.maximum(self.floor[sl], 1e-300)))


def welch_lines(x: np.ndarray, rate_hz: float, resolution_hz: float = 0.5, min_hz: float = 1.0) -> Spectrum:
    """Welch PSD with 1/resolution_hz-long Hann segments (shorter if that leaves < 8 of them)."""
    from scipy.ndimage import median_filter
    from scipy.signal import welch
    from scipy.stats import chi2

    x = np.asarray(x, dtype=float) - float(np.mean(x))
    nper = min(round(rate_hz / resolution_hz), max(len(x) // 8, 16))
    f, psd = welch(x, fs=rate_hz, window="hann", nperseg=nper, noverlap=nper // 2)
    segments = max(len(x) // nper, 1)  # non-overlapping count: fewer dof, a conservative test
    dof = 2 * segments
    half = max(1, round(FLOOR_HALF_WIDTH_HZ / float(f[1] - f[0])))
    floor = median_filter(psd, size=2 * half + 1, mode="nearest") / (chi2.median(dof) / dof)
    band = f >= min_hz
    threshold = float(chi2.isf(FALSE_ALARM / max(int(band.sum()), 1), dof) / dof)
    ratio = np.where(band & (floor > 0), psd / np.where(floor > 0, floor, 1.0), 0.0)
    i = int(np.argmax(ratio))
    return Spectrum(f, psd, floor, threshold, segments, float(f[i]), float(ratio[i]),
                    bool(ratio[i] > threshold))  # fmt: skip


def shaft_orders(rps: float, nyquist_hz: float, most: int = 10) -> list[tuple[int, float]]:
    """(order, Hz) of the shaft's harmonics below Nyquist: where imbalance (1×) and cogging (N×) sit."""
    if not math.isfinite(rps) or rps == 0:
        return []
    f0 = abs(rps)
    return [(k, k * f0) for k in range(1, most + 1) if k * f0 < nyquist_hz]
