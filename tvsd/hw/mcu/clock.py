"""MCU clock → host clock: robust linear fit over heartbeat round trips.

Each heartbeat gives (host send time, host receive time, MCU ticks when the MCU answered). The
MCU event lies somewhere inside the round trip; the midpoint is off by half the difference of the
two one-way delays, so a sample is only as good as its round trip is short. Samples whose RTT
exceeds the window's smallest RTT by more than ``rtt_margin_s`` are discarded (USB scheduling,
a busy host), which bounds each kept sample's error by (margin + jitter of the best one) / 2;
the `min_samples` fastest are always kept (beside CPU hogs round trips spread over ms and the
margin alone kept too few to ever be ready), which bounds it by half the slowest kept. A
straight line host = a + b·ticks over a sliding window then absorbs the crystal's drift (±100s of
ppm, changing slowly with temperature).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from tvsd.errors import ConfigError


def unwrap_nearest(value: int, bits: int, reference: int) -> int:
    """The integer congruent to ``value`` modulo 2**bits that lies nearest ``reference``."""
    mod = 1 << bits
    half = mod >> 1
    return reference + ((value - reference + half) % mod) - half


@dataclass(frozen=True)
class ClockSettings:
    window: int = 256  # round trips kept: at a 20 ms heartbeat, about 5 s
    rtt_margin_s: float = 200e-6  # keep samples with RTT <= min RTT of the window + this
    min_samples: int = 8  # before this, map with the nominal clock and the best sample
    outlier_sigma: float = 4.0  # second pass: drop residuals beyond this many robust sigmas

    def __post_init__(self) -> None:
        if self.window < 2 or not 2 <= self.min_samples <= self.window:
            raise ConfigError(
                f"clock sync: need 2 <= min_samples ({self.min_samples}) <= window ({self.window})"
            )
        if not self.rtt_margin_s > 0 or not self.outlier_sigma > 0:
            raise ConfigError("clock sync: rtt_margin_s and outlier_sigma must be > 0")


@dataclass(frozen=True)
class ClockFit:
    offset_s: float  # host time (s) at MCU tick 0
    seconds_per_tick: float
    drift_ppm: float  # how fast the MCU clock runs against its nominal frequency
    residual_us: float  # RMS residual of the samples used
    used: int  # samples used / held
    held: int


def _line_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares slope and intercept in closed form. Not np.polyfit: its LAPACK call may go
    to OpenBLAS's worker threads, which spin-wait, and it runs on the link's I/O thread (SCHED_FIFO
    under --realtime) at every heartbeat ack."""
    xm, ym = float(x.mean()), float(y.mean())
    dx = x - xm
    b = float(np.dot(dx, y - ym) / np.dot(dx, dx))
    return b, ym - b * xm


class ClockSync:
    """Map unwrapped MCU ticks to host time (the clock of ``time.monotonic``)."""

    def __init__(self, clock_hz: float, settings: ClockSettings | None = None) -> None:
        if clock_hz <= 0:
            raise ValueError(f"clock_hz must be positive, got {clock_hz}")
        self.clock_hz = float(clock_hz)
        self.settings = settings or ClockSettings()
        self._samples: deque[tuple[int, float, float]] = deque(maxlen=self.settings.window)
        self.fit_: ClockFit | None = None
        # to_host() runs per event: its coefficients as plain numbers, in one tuple (x_ref, y_ref,
        # b) replaced whole, so a reader on another thread (the link's I/O thread refits) never
        # mixes two fits
        self._coef: tuple[int, float, float] = (0, 0.0, 1.0 / self.clock_hz)
        # what error_bound_s needs of the last fit: the kept samples' ticks (centred on x_ref),
        # whether the slope was fitted, and half the slowest kept round trip
        self._kept: tuple[np.ndarray, bool, float] = (np.zeros(0), False, 0.0)

    @property
    def ready(self) -> bool:
        return self.fit_ is not None and self.fit_.used >= self.settings.min_samples

    def add(self, host_send: float, host_recv: float, mcu_ticks: int) -> None:
        """One heartbeat round trip: host times in seconds, MCU ticks unwrapped to 64 bits."""
        if host_recv < host_send:
            raise ValueError("a round trip cannot end before it starts")
        self._samples.append((mcu_ticks, 0.5 * (host_send + host_recv), host_recv - host_send))
        self._refit()

    def _refit(self) -> None:
        s = self.settings
        ticks = np.array([t for t, _, _ in self._samples], dtype=np.int64)
        mid = np.array([m for _, m, _ in self._samples])
        rtt = np.array([r for _, _, r in self._samples])
        # the round trips within the margin of the fastest, and at least the min_samples fastest:
        # beside a loaded machine they spread over ms and one fast outlier left too few
        k = min(s.min_samples, len(rtt))
        keep = rtt <= max(rtt.min() + s.rtt_margin_s, float(np.partition(rtt, k - 1)[k - 1]))
        # Centre both axes: ticks reach 1e12 and monotonic seconds 1e6; float64 keeps µs then.
        x_ref = int(ticks[keep][-1])
        y_ref = float(mid[keep][-1])
        x = (ticks - x_ref).astype(np.float64)
        y = mid - y_ref
        b = 1.0 / self.clock_hz
        a = 0.0
        for _ in range(2):
            if keep.sum() >= 2 and np.ptp(x[keep]) > 0:
                b, a = _line_fit(x[keep], y[keep])
            else:  # one sample: nominal rate through it
                a = float(np.mean(y[keep] - b * x[keep]))
            res = y - (a + b * x)
            mad = float(np.median(np.abs(res[keep])))
            # robust sigma, floored at the error a kept sample may have by construction
            limit = max(s.outlier_sigma * 1.4826 * mad, s.rtt_margin_s / 2)
            new_keep = keep & (np.abs(res) <= limit)
            if new_keep.sum() == keep.sum() or new_keep.sum() < min(s.min_samples, len(rtt)):
                break
            keep = new_keep
        res = y[keep] - (a + b * x[keep])
        y0, b = y_ref + float(a), float(b)
        self._coef = (x_ref, y0, b)
        fitted = bool(keep.sum() >= 2 and np.ptp(x[keep]) > 0)
        self._kept = (x[keep].copy(), fitted, float(rtt[keep].max()) / 2)
        self.fit_ = ClockFit(
            offset_s=y0 - b * x_ref,
            seconds_per_tick=b,
            drift_ppm=(1.0 / (b * self.clock_hz) - 1.0) * 1e6,
            residual_us=float(np.sqrt(np.mean(res**2))) * 1e6,
            used=int(keep.sum()),
            held=len(self._samples),
        )

    def to_ticks(self, host_s: float) -> int:
        """The MCU tick count at a host time (the inverse of to_host); needs a fit."""
        if self.fit_ is None:
            raise ValueError("no clock fit yet: no heartbeat round trip")
        x_ref, y_ref, b = self._coef
        return x_ref + round((host_s - y_ref) / b)

    def error_bound_s(self, mcu_ticks: int) -> float:
        """The worst error of to_host(mcu_ticks), given that each kept sample's midpoint is within
        half its round trip of the MCU's event (the event lies inside the round trip): the fit is
        linear in the samples, ŷ(x) = Σ wᵢ(x)·yᵢ with wᵢ = 1/n + (x − x̄)(xᵢ − x̄)/Sxx for a fitted
        line, so its error is at most Σ|wᵢ(x)| times the largest sample error — 1 in the middle of
        the kept samples, up to ~4 at their ends and growing outside them. With the nominal
        slope (one sample, or all at one tick) the crystal's tolerance is added: 200 ppm of the
        distance to them. NaN before any fit."""
        if self.fit_ is None:
            return float("nan")
        xs, fitted, half_rtt = self._kept
        x = float(mcu_ticks - self._coef[0])
        if not fitted:
            return half_rtt + 200e-6 * float(np.abs(x - xs).min()) / self.clock_hz
        dx = xs - xs.mean()
        w = 1.0 / len(xs) + (x - xs.mean()) * dx / float(np.dot(dx, dx))
        return half_rtt * float(np.abs(w).sum())

    def to_host(self, mcu_ticks: int) -> float:
        """Host time (s) of an MCU tick count (unwrapped). Before any sample: NaN."""
        if self.fit_ is None:
            return float("nan")
        x_ref, y_ref, b = self._coef
        return y_ref + b * (mcu_ticks - x_ref)


def warm_up(clock_hz: float = 16e6) -> None:
    """Run one fit on made-up round trips. The first least-squares call sets up LAPACK's work
    buffers; under mlockall every one of their pages is faulted in then: 11 ms alone, 64 ms
    measured in the SIL daemon at the first heartbeat ack, which tripped the firmware's 50 ms
    watchdog. McuLink.open() calls this, before the link reads or sends anything."""
    sync = ClockSync(clock_hz)
    for k in range(3):
        sync.add(k * 0.01, k * 0.01 + 1e-4, round(k * 0.01 * clock_hz))
