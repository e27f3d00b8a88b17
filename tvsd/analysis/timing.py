"""The speed's timing reference: the doctor's ω is the mean over each sample's period.

The doctor's delay is the command-to-response lag measured against a stated reference: `u` as
`# u_sampling:` declares it (dataset.load) and ω the **period mean**, the mean speed over the
interval that ends at the row's time. That is what tvsd's recordings hold (`tvsctl sim record`:
the simulated period mean; `tvsctl export`: the encoder frames' angle difference over each 1 ms)
and what an encoder-only bench's backward difference is: (φ[k] − φ[k−1])·fs is that mean exactly,
so a recorded φ carries the reference. A speed with other timing — a tach behind its anti-alias
filter, a speed sampled at the instant, a control thread's filtered speed logged late — shifts
the whole response in time, and the doctor sees the shift as a `delay` of that size: a SIL null
whose ω column was one sample late was named `delay` 1.08 ms (the 1 ms SIL delay reads 1.14 ms).

`speed_lag` measures the recorded ω against φ's backward difference in the doctor's band; where
the lag is significant the dataset's speed is the recorded ω advanced by it (`retimed`), so the
model and the recording agree on the convention instead of the delay absorbing it.
docs/measurements/lagref.md has the figures.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import butter, filtfilt

BAND_HZ = 100.0  # the doctor's band (prep.Band's corner): the timing that matters is the band's
MIN_LAG_SAMPLES = 0.1  # below this the baseline's two input columns hold the shift anyway
MIN_SHARE = 0.5  # a shift must explain half of ω's in-band difference from the period mean
MAX_LAG = 8.0  # samples scanned each way (a control thread's speed: 3 ms at 1 kHz)
GRID = 0.05
EDGE = 16  # samples at each end left out of the share (the shift's wrap)


def retimed(omega: np.ndarray, lag: float) -> np.ndarray:
    """ω advanced by `lag` samples, an all-pass shift (FFT phase), so its noise keeps its
    spectrum: φ's backward difference in its place has the encoder's quantisation, white in φ,
    and a SIL null was named `colored_noise` for it. The line through the ends is taken out
    first and put back shifted, so the circular shift meets no step at the wrap."""
    n = len(omega)
    k = np.arange(n)
    line = omega[0] + (omega[-1] - omega[0]) * k / max(n - 1, 1)
    f = np.fft.rfftfreq(n)
    shifted = np.fft.irfft(np.fft.rfft(omega - line) * np.exp(2j * np.pi * f * lag), n)
    return shifted + omega[0] + (omega[-1] - omega[0]) * (k + lag) / max(n - 1, 1)


def reference_speed(omega: np.ndarray, phi: np.ndarray, rate_hz: float) -> np.ndarray:
    """The period mean from the angle: (φ[k] − φ[k−1])·fs; row 0 keeps the recorded ω."""
    return np.concatenate([omega[:1], np.diff(phi) * rate_hz])


def speed_lag(omega: np.ndarray, phi: np.ndarray, rate_hz: float) -> tuple[float, float]:
    """(lag in samples, share of the in-band difference it explains) of the recorded ω behind
    the period mean of φ.

    Both are low-passed zero-phase at the doctor's corner; the lag is the all-pass shift of ω
    that leaves the least in-band difference from the period mean (a scan over ±MAX_LAG samples
    by the cross-spectrum, 0.05 then 0.001 sample apart): unbiased by the noise of
    either, where the slope on the derivative was not (a 1-sample lag read 0.89, 3 read 2.65).
    The share says whether a shift is what separates them: ≥ 0.8 on SIL speeds made late by 1–3
    samples, ≤ 0.04 on a tach's noise or bench-dev's (docs/measurements/lagref.md). (nan, 0)
    when there is nothing to compare.

    The 0.05 grid is evaluated only near the peaks of the band-limited cross-correlation, found
    on a grid of 1/`_upsampling` sample from one inverse FFT (memory O(n)); the whole scan by the
    cross-spectrum cost lags × bins (125 MB per 32 lags on 1 h at 2 kHz, 321 lags)."""
    n = len(omega)
    corner = min(BAND_HZ, 0.4 * rate_hz)
    if n < 64:
        return math.nan, 0.0
    b, a = butter(4, corner / (rate_hz / 2))
    cut = n // 20  # the filters' edge transients
    w = filtfilt(b, a, omega)[cut : n - cut]
    wbar = filtfilt(b, a, reference_speed(omega, phi, rate_hz))[cut : n - cut]
    f = np.fft.rfftfreq(len(w))
    keep = f <= 1.5 * corner / rate_hz
    cross = np.fft.rfft(_detrended(w)) * np.conj(np.fft.rfft(_detrended(wbar)))
    cross[~keep] = 0.0
    fk, ck = f[keep], cross[keep]

    def inner(grid: np.ndarray) -> np.ndarray:  # <ω advanced by λ, ω̄> per λ (Parseval, one-sided)
        per = max(1, INNER_VALUES // max(len(fk), 1))  # lags at a time: bounded memory
        parts = [
            np.exp(2j * np.pi * np.outer(g, fk)) @ ck for g in np.array_split(grid, len(grid) // per + 1)
        ]
        return np.real(np.concatenate(parts))

    coarse = np.arange(-MAX_LAG, MAX_LAG + GRID / 2, GRID)
    coarse = coarse[_near_peaks(cross, len(w), float(fk[-1]), coarse)]
    best = float(coarse[int(np.argmax(inner(coarse)))])
    fine = best + np.linspace(-GRID, GRID, 101)  # then to 0.001 sample around the best
    lag = float(fine[int(np.argmax(inner(fine)))])
    before = float(np.sum((w - wbar)[EDGE:-EDGE] ** 2))
    if not before > 0:
        return 0.0, 0.0
    left = float(np.sum((retimed(w, lag) - wbar)[EDGE:-EDGE] ** 2))
    return lag, max(0.0, 1.0 - left / before)


INNER_VALUES = 1 << 20  # complex exponentials per block of the exact scan (16 MB)


def _upsampling(f_top: float) -> int:
    """Points per sample of the peak search: 8 or more per period of the band's top frequency
    (cycles per sample), so every peak of the cross-correlation is a local maximum of the grid
    within one grid step."""
    return max(1, math.ceil(8.0 * f_top))


def _near_peaks(cross: np.ndarray, n: int, f_top: float, lags: np.ndarray) -> np.ndarray:
    """Which of `lags` lie within a grid step (+ GRID) of a local maximum of the cross-
    correlation Re Σ_k cross_k·exp(2jπ k λ / n) on the grid λ = m/U, |λ| ≤ MAX_LAG: its
    irfft, zero-padded to U·n (the sum's Hermitian weights shift it by the constant Re cross₀
    only, which moves no maximum)."""
    up = _upsampling(f_top)
    corr = np.fft.irfft(cross, up * n)
    m = np.arange(-math.ceil(MAX_LAG * up), math.ceil(MAX_LAG * up) + 1)
    c = corr[m % (up * n)]
    higher_left = np.concatenate([[True], c[1:] >= c[:-1]])
    higher_right = np.concatenate([c[:-1] >= c[1:], [True]])
    peaks = m[higher_left & higher_right] / up
    reach = 1.0 / up + GRID
    return np.any(np.abs(lags[:, None] - peaks[None, :]) <= reach + 1e-12, axis=1)


def _detrended(x: np.ndarray) -> np.ndarray:
    return x - np.linspace(x[0], x[-1], len(x))


def off_reference(lag: float, share: float) -> bool:
    """Whether the recorded ω is the period mean shifted in time (not merely noisier)."""
    return bool(np.isfinite(lag)) and abs(lag) >= MIN_LAG_SAMPLES and share >= MIN_SHARE
