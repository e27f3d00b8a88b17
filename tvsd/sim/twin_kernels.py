"""Compiled inner loops of the MPU6050 twins (tvsd.sim.mpu6050, tvsd.sim.imu_motion).

Why: in the SIL devices' process the twins compute each poll's samples inside the bus thread's
request, under the GIL beside the plant's thread. Per sensor and poll that was ~0.35 ms of CPU,
almost all of it fixed cost per call (scipy's sosfilt wrapper, a Python loop per sample for the
mounts' leaky rate, a dozen small numpy calls), not per sample. These kernels do the same
arithmetic, in the same order (the results are bit-for-bit those of the numpy/scipy code they
replace: tests/test_twin_kernels.py), without the GIL.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def dlpf_counts(
    sos: np.ndarray, zi: np.ndarray, x: np.ndarray, lsb: np.ndarray, offset: np.ndarray
) -> np.ndarray:
    """scipy.signal.sosfilt(sos, x, axis=0, zi=zi) (its direct form II transposed, in its order;
    `zi` (sections, 2, channels) updated in place), then the ADC: rint(y / lsb + offset), clipped
    to int16's range. x: (n, channels) float64; returns (n, channels) int64 counts."""
    n, channels = x.shape
    out = np.empty((n, channels), np.int64)
    for c in range(channels):
        for i in range(n):
            cur = x[i, c]
            for s in range(sos.shape[0]):
                new = sos[s, 0] * cur + zi[s, 0, c]
                zi[s, 0, c] = sos[s, 1] * cur - sos[s, 4] * new + zi[s, 1, c]
                zi[s, 1, c] = sos[s, 2] * cur - sos[s, 5] * new
                cur = new
            v = np.rint(cur / lsb[c] + offset[c])
            out[i, c] = int(min(max(v, -32768.0), 32767.0))
    return out


@njit(cache=True, nogil=True)
def leaky_rate(
    s: np.ndarray, ends: np.ndarray, accel: np.ndarray, stop: float, tau: float, omega: float, pos: float
) -> tuple[np.ndarray, float, float]:
    """The mounts' rate ω at sim times `s` (increasing, ≥ pos): ω̇ = a − ω/τ integrated exactly
    over each piece where the acceleration is constant (`accel[k]` until `ends[k]`, the last one
    held until `stop`, 0 after), from ω = `omega` at `pos`. Returns (ω at s, the last time, ω there)."""
    rate = np.empty(s.size)
    k, last = 0, ends.size - 1
    for i in range(s.size):
        si = s[i]
        while pos < si:
            while k < last and ends[k] <= pos:
                k += 1
            if ends[k] > pos:
                end = ends[k]
            elif pos < stop:
                end = stop
            else:
                end = math.inf
            nxt = min(si, end)
            a = accel[k] if pos < stop else 0.0
            c = math.exp(-(nxt - pos) / tau)
            omega = c * omega + tau * (1.0 - c) * a
            pos = nxt
        rate[i] = omega
    return rate, pos, omega


def warm() -> None:
    """Compile (or load from numba's cache) both kernels now, on dummy data: a twin built at a
    bus's start must not spend a first poll compiling (seconds on a loaded machine: the reader
    declared the sensor lost before its first sample)."""
    sos = np.array([[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]])
    dlpf_counts(sos, np.zeros((1, 2, 6)), np.zeros((1, 6)), np.ones(6), np.zeros(6))
    leaky_rate(np.zeros(1), np.ones(1), np.zeros(1), 1.0, 1.0, 0.0, 0.0)
