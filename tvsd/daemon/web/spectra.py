"""Both IMUs' recent samples and their Welch spectra, for the live view.

The daemon hands every IMU batch over on the event loop's thread (`push`: a copy into a
preallocated ring, no allocation per sample). `spectra(rps)` is asked once a second while a
browser watches: a Welch PSD per sensor and axis (gyro x y z, accel x y z) over the newest
`spectrum_s`, with about 2 Hz resolution (segments of the next power of two above rate/2,
Hann window, half overlap: 15 averages in 4 s at 1 kHz, so a shaft line stands clear of the
noise, unlike a raw periodogram), and the shaft orders k·|rps| below Nyquist to mark.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.signal import welch

SENSORS = ("pl", "sa")
CHANNELS = ("gx", "gy", "gz", "ax", "ay", "az")  # gyro rad/s, accel m/s²
MAX_ORDERS = 10
FLOOR_DB = -200.0  # a channel that is exactly constant (a PSD of 0) shows at this level


class ImuWindow:
    """The newest `seconds` of both sensors' gyro and accel, at `rate_hz`."""

    def __init__(self, rate_hz: float, seconds: float) -> None:
        self.rate_hz = rate_hz
        self.size = max(16, round(rate_hz * seconds))
        self.nperseg = min(self.size, 1 << math.ceil(math.log2(max(rate_hz / 2, 8))))
        self._ring = {s: np.zeros((self.size, len(CHANNELS))) for s in SENSORS}
        self._count = dict.fromkeys(SENSORS, 0)  # samples ever pushed

    def push(self, sensor: str, gyro: np.ndarray, accel: np.ndarray) -> None:
        """One reader batch ((n, 3) each): into the ring (the newest `size` kept)."""
        ring = self._ring.get(sensor)
        if ring is None or len(gyro) == 0:
            return
        n = len(gyro)
        if n > self.size:
            gyro, accel, n = gyro[-self.size :], accel[-self.size :], self.size
        start = self._count[sensor] % self.size
        first = min(n, self.size - start)
        ring[start : start + first, :3] = gyro[:first]
        ring[start : start + first, 3:] = accel[:first]
        if first < n:
            ring[: n - first, :3] = gyro[first:]
            ring[: n - first, 3:] = accel[first:]
        self._count[sensor] += n

    def samples(self, sensor: str) -> np.ndarray:
        """The sensor's samples in the ring, oldest first (a copy)."""
        count, ring = self._count[sensor], self._ring[sensor]
        if count < self.size:
            return ring[:count].copy()
        start = count % self.size
        return np.concatenate((ring[start:], ring[:start]))

    def snapshot(self) -> dict[str, np.ndarray]:
        """Both sensors' samples (copies): taken on the thread that pushes."""
        return {s: self.samples(s) for s in SENSORS}

    def spectra(self, rps: float) -> dict[str, Any] | None:
        return self.spectra_of(self.snapshot(), rps)

    def spectra_of(self, samples: dict[str, np.ndarray], rps: float) -> dict[str, Any] | None:
        """{"f": Hz, "psd_db": {sensor: {channel: dB}}, "orders": Hz, "rps", "seconds", "nperseg"},
        or None before any sensor has a full segment. dB re 1 (rad/s)²/Hz (gyro) or (m/s²)²/Hz.
        Any thread: reads only `samples` and settings."""
        out: dict[str, dict[str, list[float]]] = {}
        freqs: np.ndarray | None = None
        for sensor in SENSORS:
            x = samples[sensor]
            if len(x) < self.nperseg:
                continue
            freqs, p = welch(x, fs=self.rate_hz, nperseg=self.nperseg, axis=0)
            db = 10.0 * np.log10(np.maximum(p, 10.0 ** (FLOOR_DB / 10)))
            out[sensor] = {c: np.round(db[:, i], 1).tolist() for i, c in enumerate(CHANNELS)}
        if freqs is None:
            return None
        shaft = abs(rps) if math.isfinite(rps) else 0.0
        nyquist = self.rate_hz / 2
        orders = [k * shaft for k in range(1, MAX_ORDERS + 1) if shaft > 0.5 and k * shaft < nyquist]
        return {
            "f": np.round(freqs, 3).tolist(),
            "psd_db": out,
            "orders": orders,
            "rps": shaft,
            "seconds": self.size / self.rate_hz,
            "nperseg": self.nperseg,
        }
