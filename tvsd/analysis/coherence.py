"""Where the residual follows the speed reference: the excitation's own lines in closed loop.

A rigid model that misfits the drive's response a little leaves, in closed loop, a line in the
residual at each line of the reference's excitation (identify's multisine: 0.2–8 Hz), the
stronger the more command the line takes. The line scan leaves out the reference's lines, found
in the reference's own periodogram; but there the steps' broadband spectrum can drown a line
(identify's 8.0 Hz line stood 4–5× its local level, short of the scan's 12.8×, while the residual
held a line 23× its own level at 7.99 Hz: three of four closed-loop null alarms of seed 62, two by
the line scan and one by the residual spectrum's peak, at 7.91 Hz).

What tells the excitation's misfit from a structural mode is not the line's size but whether it
follows the reference: misfit is the drive's response to it, a mode's torque is not. The
magnitude-squared coherence of the residual with the reference over K non-overlapping segments,
where the residual is white noise independent of the reference, exceeds c with probability
(1 − c)^(K − 1) whatever the reference (Carter 1987, for Gaussian noise): the threshold comes from
that law, not from a simulation. A frequency where the coherence passes its 1 − ALPHA point is the
reference's, as a line of its periodogram is.
"""

from __future__ import annotations

import numpy as np

# Segments of the coherence estimate: 1 s, so a 30 s record holds K = 29 and the null's K − 1
# degrees give the test its power — the excitation runs 20 s of the 30 and its misfit follows the
# reference only there. Tried on seed 62's three 8 Hz alarms (p of the coherence at 8 Hz): 4 s
# segments (K 7) 0.004, 0.0000, 0.027; 2 s (K 14) 0.011, 0.0002, 0.0002; 1 s (K 29) all < 1e-4.
# The price is resolution: a coherent frequency leaves out 1 Hz of the scan (identify's 0.2–8 Hz
# multisine band, where the residual follows it), and by chance ~1 % of the band (~0.5 Hz) per file.
SEGMENT_S = 1.0
ALPHA = 0.01  # per frequency of the segments' grid (≈ 50 in the scanned band)
MIN_SEGMENTS = 4


def threshold(segments: int, alpha: float = ALPHA) -> float:
    """The coherence independent noise passes with probability `alpha`: (1 − c)^(K−1) = α."""
    return float(1.0 - alpha ** (1.0 / (segments - 1)))


def coherence(
    e: np.ndarray, x: np.ndarray, fs: float, seg_s: float = SEGMENT_S
) -> tuple[np.ndarray, np.ndarray, int]:
    """The segments' frequencies, the magnitude-squared coherence of `e` with `x` there (Hann
    window, each segment's mean removed) and the number of segments K (0: too short)."""
    n = min(len(e), len(x))
    seg = max(round(seg_s * fs), 8)
    k = n // seg
    if k < MIN_SEGMENTS:
        return np.zeros(0), np.zeros(0), 0
    w = np.hanning(seg)

    def spectra(s: np.ndarray) -> np.ndarray:
        blocks = s[: k * seg].reshape(k, seg)
        return np.fft.rfft((blocks - blocks.mean(axis=1, keepdims=True)) * w, axis=1)

    E, X = spectra(e), spectra(x)
    sxy = np.abs(np.sum(np.conj(X) * E, axis=0)) ** 2
    sxx = np.sum(np.abs(X) ** 2, axis=0)
    see = np.sum(np.abs(E) ** 2, axis=0)
    c = sxy / np.maximum(sxx * see, 1e-300)
    c[(sxx <= 0) | (see <= 0)] = 0.0
    return np.fft.rfftfreq(seg, 1.0 / fs), c, k


def coherent(e: np.ndarray, x: np.ndarray, fs: float, f: np.ndarray, alpha: float = ALPHA) -> np.ndarray:
    """For each frequency of `f`: does `e` follow `x` there (the coherence at the nearest
    frequency of the segments' grid above its 1 − α point)? All False where too short."""
    fc, c, k = coherence(e, x, fs)
    f = np.asarray(f, dtype=float)
    if k == 0:
        return np.zeros(f.shape, dtype=bool)
    idx = np.clip(np.rint(f / fc[1]).astype(int), 0, len(fc) - 1)
    return np.asarray(c > threshold(k, alpha))[idx]
