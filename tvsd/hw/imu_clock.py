"""Clocks for the IMU reader, and the fit of each sensor's own clock against host time.

The MPU6050's sample clock runs a few % off nominal and has no counter: the reader numbers
samples itself and this fit turns sample numbers into host times. The rate comes from least
squares with outlier rejection over (host read time, newest sample number) pairs; each FIFO
epoch's phase from the lower envelope of t - K/rate (K = newest sample number at host time t,
so K = floor(rate·(t - t0))). A sample's time is t0 + k/rate, when it entered the FIFO.
`ManualClock` lets tests and `--sil` run the reader faster than real time.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Protocol

import numpy as np


class Clock(Protocol):
    def now(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """Real time."""

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class ManualClock:
    """Simulated time: sleeping advances it at once, so a capture runs faster than real time."""

    def __init__(self, start: float = 0.0) -> None:
        self.t = start

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            self.t += seconds


def _line_rate(t: np.ndarray, k: np.ndarray, group: np.ndarray) -> tuple[float, float] | None:
    """Slope of k against t (one offset per group) and its standard error; two rounds of
    outlier rejection. None when the span is too short to beat the nominal rate."""
    keep = np.ones(len(t), dtype=bool)
    out = None
    for _ in range(2):
        tk, kk, g = t[keep], k[keep], group[keep]
        sizes = np.bincount(g, minlength=group.max() + 1).clip(min=1)
        dt = tk - (np.bincount(g, tk, minlength=sizes.size) / sizes)[g]
        dk = kk - (np.bincount(g, kk, minlength=sizes.size) / sizes)[g]
        sxx = float(np.sum(dt * dt))
        if sxx < 0.01:  # under ~0.1 s of span
            return out
        rate = float(np.sum(dt * dk) / sxx)
        resid = dk - rate * dt
        # K is floor(rate t): at least the 1/sqrt(12) sample of uniform quantization
        spread = max(float(np.std(resid)), 12**-0.5)
        out = (rate, spread / np.sqrt(sxx))
        scale = max(1.4826 * float(np.median(np.abs(resid - np.median(resid)))), 1 / 3)
        keep[keep] = np.abs(resid - np.median(resid)) <= 3 * scale
    return out


class ClockFit:
    """Fit of the sensor's sample clock to host time: a shared rate, one phase per epoch."""

    PHASE_POINTS = 100  # 2 s of polls at 50 Hz
    MAX_EPOCHS = 64  # phases kept for the loss refinement (SensorReader.lost)

    def __init__(self, nominal_hz: float, window: int = 4096) -> None:
        self.nominal_hz = nominal_hz
        self.points: deque[tuple[float, int, int]] = deque(maxlen=window)  # (t, K, epoch)
        self.tails: dict[int, deque[tuple[float, int]]] = {}  # each epoch's latest points
        self.dropped_fix = 0  # loss refinement of epochs dropped from tails
        self._rate: float | None = None
        self._adds = self._rate_adds = 0  # the rate is refitted only after new points
        self.rate_stderr = float("inf")  # standard error of the last fitted rate, Hz

    def add(self, t: float, newest: int, epoch: int) -> None:
        self.points.append((t, newest, epoch))
        self._adds += 1
        self.tails.setdefault(epoch, deque(maxlen=self.PHASE_POINTS)).append((t, newest))
        while len(self.tails) > self.MAX_EPOCHS:  # keep what SensorReader.lost needs
            oldest = min(self.tails)
            rate = self.rate()
            self.dropped_fix += round((self.t0(oldest + 1, rate) - self.t0(oldest, rate)) * rate)
            del self.tails[oldest]

    def rate(self) -> float:
        """Sensor samples per second of host time; its standard error goes to rate_stderr.

        First by least squares with one offset per epoch (each epoch's numbering may be off by
        whole samples at its estimated start), then refitted over chains of epochs linked by
        unambiguous whole-period phase steps (see below). Reads more than 3 robust sigmas (at
        least 1 sample) off the line are dropped.
        """
        if len(self.points) < 8:
            return self.nominal_hz  # rate_stderr stays inf: not fitted yet
        # refit after a fraction of new points: every read while young, every 2 s when mature
        due = min(max(1, len(self.points) // 8), 100)
        if self._rate is not None and self._adds - self._rate_adds < due:
            return self._rate
        p = np.asarray(self.points)
        t, k = p[:, 0], p[:, 1]
        _, group = np.unique(p[:, 2], return_inverse=True)
        pooled = _line_rate(t, k, group)
        if pooled is None:
            self.rate_stderr = float("inf")
            return self.nominal_hz
        rate, stderr = pooled
        # Chain epochs whose phase step is clearly a whole number of periods into segments with
        # one numbering, and refit with one offset per segment: a flaky bus leaves many short
        # epochs, each holding little slope information on its own. Epochs of a few reads have
        # phases known to about a sample only, so they are left out of the chaining.
        sizes = np.bincount(group)
        solid = sizes[group] >= 5
        if solid.any():
            t, k = t[solid], k[solid]
            _, group = np.unique(group[solid], return_inverse=True)
            first_t = np.full(group.max() + 1, np.inf)
            np.minimum.at(first_t, group, t)
            phase = np.full(group.max() + 1, np.inf)
            np.minimum.at(phase, group, t - k / rate)
            x = np.diff(phase) * rate
            near = np.abs(x - np.rint(x)) < 0.25  # phases good to ~0.2 period with >= 5 reads
            sure = stderr * np.diff(first_t) < 0.1  # the rate's error adds < 0.1 period
            link = near & sure
            steps = np.concatenate([[0.0], np.cumsum(np.where(link, np.rint(x), 0.0))])
            segment = np.concatenate([[0], np.cumsum(~link)])
            fit = _line_rate(t, k + steps[group], segment[group])
            if fit is not None:
                rate, stderr = fit
        # a fit more than 10 % off nominal is not an MPU6050 clock: distrust it
        if abs(rate / self.nominal_hz - 1) >= 0.1:
            rate, stderr = self.nominal_hz, float("inf")
        self._rate, self._rate_adds, self.rate_stderr = rate, self._adds, stderr
        return rate

    def t0(self, epoch: int, rate: float | None = None) -> float:
        """Time of sample number 0 on the epoch's phase (the latest epoch's if it has none).

        t is taken after the count read returns, so host delays only make t later: t - K/rate
        >= t0 + (least latency), and its minimum over recent points (phases spread over a
        sample period) is t0 to a small fraction of a sample: a lower envelope, as NTP's
        minimum-delay filter. Recent points only, so a rate error cannot drift it.
        """
        rate = rate or self.rate()
        if not self.tails:
            raise ValueError("no clock points yet")
        mine = np.asarray(self.tails.get(epoch) or self.tails[max(self.tails)])
        return float(np.min(mine[:, 0] - mine[:, 1] / rate))

    def newest_at(self, t: float) -> int:
        """Expected newest sample number at host time t, on the latest epoch's phase."""
        rate = self.rate()
        return int(np.floor((t - self.t0(max(self.tails), rate)) * rate))

    def times(self, k: np.ndarray, epoch: int) -> np.ndarray:
        rate = self.rate()
        return self.t0(epoch, rate) + np.asarray(k, dtype=np.float64) / rate
