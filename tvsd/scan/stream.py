"""The scan pipeline fed as data arrives, as the daemon's point stream needs it.

Pulses (arrival order) and IMU/drive samples (time order) come in separately. A point is computed
once its data are there: the zero pulses its estimator needs (centred: the next one, ≤ one
revolution later; causal: none after it) and, with compensation, IMU samples up to the last of
those pulses (the FIFO delivers them within a few ms), judged for each pulse. Each computation
runs the batch pipeline on a short buffer — the last `KEEP_ZERO` zero pulses and the samples the
σ window needs — and returns the points not sent before (tvsd.scan.points.Point).

It runs on the daemon's event loop for every SA batch, so it keeps what it can across calls
(re-running the pipeline over the whole buffer took 1.2 ms of CPU for each batch that completes a
point, 3.6 ms under cProfile):
- the samples in a ring (`_Ring`): a batch costs its own length, not a copy of the window;
- the cleaned pulses (tvsd.scan.pulses.clean), until the next pulse; the known acceleration's
  grids, windows and integrals that β and σ ask for more than once (tvsd.scan.compensation);
- only the optical pulses not sent yet go through the estimator and the σ model; the others'
  rows were computed and sent (or dropped) before.
The output is the whole-buffer pipeline's: β, x, y, z and the flags bit for bit; σ and the
vibration to rounding (the σ model's FFT length follows the widest row computed together:
tests/test_scan_stream.py compares both on SIL data).
"""

from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np

from tvsd.scan.compensation import KnownAccel
from tvsd.scan.pipeline import process
from tvsd.scan.points import Point
from tvsd.scan.pulses import OPTICAL, ZERO, CleanPulses, clean
from tvsd.scan.settings import ScanSettings

KEEP_ZERO = 12  # ≥ the running median's 9 intervals + the estimator's 3 knots


class _Ring:
    """The newest `keep` values of a series, contiguous: appending costs the batch, reading is a view."""

    def __init__(self, keep: int) -> None:
        self.keep = keep
        self._buf = np.empty(2 * max(keep, 1))
        self._start = self._end = 0

    def __len__(self) -> int:
        return self._end - self._start

    def extend(self, x: np.ndarray) -> int:
        """Append; how many of the oldest fell out."""
        n, held = len(x), len(self)
        if n >= self.keep:
            self._buf[: self.keep] = x[n - self.keep :]
            self._start, self._end = 0, self.keep
            return held + n - self.keep
        if self._end + n > len(self._buf):  # move the kept values to the front (≤ keep of them)
            self._buf[:held] = self._buf[self._start : self._end]
            self._start, self._end = 0, held
        self._buf[self._end : self._end + n] = x
        self._end += n
        drop = max(len(self) - self.keep, 0)
        self._start += drop
        return drop

    def view(self) -> np.ndarray:
        return self._buf[self._start : self._end]


class PointStream:
    def __init__(
        self,
        settings: ScanSettings,
        phi: float,
        gamma: float,
        tick_s: float,
        compensate: bool = True,
        damping: float = 0.0,
    ) -> None:
        """`damping`: λ of the drive model (tvsd.scan.compensation.DriveModel)."""
        self.settings, self.phi, self.gamma, self.tick_s = settings, phi, gamma, tick_s
        self.damping = damping
        self.compensate = compensate
        self._pulses: deque[tuple[int, int]] = deque()
        self._zeros = 0
        self._keep = int((settings.vibration_window_s + 0.5) * settings.imu_rate_hz)
        self._imu = _Ring(self._keep)
        self._drive = _Ring(self._keep)
        self._imu_t0 = np.nan  # MCU time of the oldest kept sample's start
        self._last_sent = -np.inf
        self._pending: deque[float] = deque()  # optical pulse times not yet turned into points
        self._data_until = -np.inf  # pulses are complete up to here (the latest zero pulse, centred)
        self._cleaned: CleanPulses | None = None  # clean() of `_pulses`, until the next pulse

    @property
    def _imu_end(self) -> float:
        return self._imu_t0 + len(self._imu) / self.settings.imu_rate_hz if len(self._imu) else -np.inf

    def add_samples(self, t0: float, imu: np.ndarray, drive: np.ndarray) -> list[Point]:
        """IMU and drive samples on the IMU grid; t0 = start of the first, in MCU time."""
        if not len(self._imu):
            self._imu_t0 = t0
        excess = self._imu.extend(np.asarray(imu, dtype=np.float64))
        self._drive.extend(np.asarray(drive, dtype=np.float64))
        self._imu_t0 += excess / self.settings.imu_rate_hz
        return self._emit()

    def add_pulse(self, kind: int, ticks: int) -> list[Point]:
        """One pulse in arrival order; returns the points that are now complete."""
        t = ticks * self.tick_s
        self._pulses.append((kind, ticks))
        self._cleaned = None
        if kind == ZERO:
            self._zeros += 1
            while self._zeros > KEEP_ZERO:
                old_kind, _ = self._pulses.popleft()
                self._zeros -= old_kind == ZERO
            if self.settings.estimator == "centred":
                self._data_until = max(self._data_until, t)
        elif kind == OPTICAL and t > self._last_sent:
            self._pending.append(t)
            if self.settings.estimator == "causal":
                self._data_until = max(self._data_until, t)
        return self._emit()

    def _complete_until(self) -> float:
        """Optical pulses up to here have all their data. Without compensation: the pulses
        (`_data_until`). With it, also the IMU past the last pulse each estimate uses: for the
        centred estimator the newest zero pulse the IMU has passed, for the causal one the IMU's
        end. Judged per pulse, not by the newest zero pulse: IMU batches (every ~20–40 ms) and
        turns (40 ms at 25 rev/s) beat, and waiting for the IMU to pass the newest pulse held
        every point for up to 10 turns (430 ms measured)."""
        if not self.compensate:
            return self._data_until
        if self.settings.estimator == "causal":
            return min(self._data_until, self._imu_end - 1e-9)
        covered = -np.inf
        for kind, ticks in reversed(self._pulses):
            t = ticks * self.tick_s
            if kind == ZERO and t < self._imu_end:
                covered = t
                break
        return min(self._data_until, covered)

    def _ready(self, until: float) -> bool:
        return bool(self._pending) and self._pending[0] <= until and self._zeros >= 3

    def _clean(self) -> CleanPulses:
        if self._cleaned is None:
            n = len(self._pulses)
            kinds = np.fromiter((k for k, _ in self._pulses), dtype=np.int8, count=n)
            ticks = np.fromiter((t for _, t in self._pulses), dtype=np.int64, count=n)
            self._cleaned = clean(kinds, ticks, self.tick_s)
        return self._cleaned

    def _emit(self) -> list[Point]:
        until = self._complete_until()
        if not self._ready(until):
            return []
        pulses = self._clean()
        # Only the optical pulses that can be sent now: the rows of the others are settled.
        new = (pulses.opt_t > self._last_sent) & (pulses.opt_t <= until)
        # What the data allowed is settled: points dropped now (anomalies, gaps) stay dropped.
        while self._pending and self._pending[0] <= until:
            self._pending.popleft()
        if not new.any():
            return []
        known = None
        if len(self._imu):
            rate = self.settings.imu_rate_hz
            known = KnownAccel.build(
                self._imu_t0, 1.0 / rate, self._imu.view(), self._drive.view(), self.damping
            )
        res = process(
            replace(pulses, opt_t=pulses.opt_t[new], opt_idx=pulses.opt_idx[new]),
            self.phi,
            self.gamma,
            self.settings,
            known,
            compensate=self.compensate and known is not None,
        )
        if len(res.cloud):
            self._last_sent = float(res.cloud.t[-1])
        return list(res.cloud.points())
