"""The whole-window point stream (tvsd/scan/stream.py before it kept state across calls): the
reference tests/test_scan_stream.py compares the incremental stream with. Not used by tvsd.

Pulses (arrival order) and IMU/drive samples (time order) come in separately. A point is computed
once its data are there: the zero pulses its estimator needs (centred: the next one, ≤ one
revolution later; causal: none after it) and, with compensation, IMU samples up to the last of
those pulses (the FIFO delivers them within a few ms), judged for each pulse. Each computation
runs the batch pipeline on a short buffer — the last `KEEP_ZERO` zero pulses and the samples the
σ window needs — and returns the points not sent before (tvsd.scan.points.Point).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from tvsd.scan.compensation import KnownAccel
from tvsd.scan.pipeline import process
from tvsd.scan.points import Point
from tvsd.scan.pulses import OPTICAL, ZERO, clean
from tvsd.scan.settings import ScanSettings

KEEP_ZERO = 12  # ≥ the running median's 9 intervals + the estimator's 3 knots


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
        self._imu: deque[float] = deque()
        self._drive: deque[float] = deque()
        self._imu_t0 = np.nan  # MCU time of the oldest kept sample's start
        self._last_sent = -np.inf
        self._pending: deque[float] = deque()  # optical pulse times not yet turned into points
        self._data_until = -np.inf  # pulses are complete up to here (the latest zero pulse, centred)
        self._keep = int((settings.vibration_window_s + 0.5) * settings.imu_rate_hz)

    @property
    def _imu_end(self) -> float:
        return self._imu_t0 + len(self._imu) / self.settings.imu_rate_hz if self._imu else -np.inf

    def add_samples(self, t0: float, imu: np.ndarray, drive: np.ndarray) -> list[Point]:
        """IMU and drive samples on the IMU grid; t0 = start of the first, in MCU time."""
        if not self._imu:
            self._imu_t0 = t0
        self._imu.extend(imu.tolist())
        self._drive.extend(drive.tolist())
        excess = max(len(self._imu) - self._keep, 0)
        for _ in range(excess):
            self._imu.popleft()
            self._drive.popleft()
        self._imu_t0 += excess / self.settings.imu_rate_hz
        return self._emit()

    def add_pulse(self, kind: int, ticks: int) -> list[Point]:
        """One pulse in arrival order; returns the points that are now complete."""
        t = ticks * self.tick_s
        self._pulses.append((kind, ticks))
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

    def _emit(self) -> list[Point]:
        until = self._complete_until()
        if not self._ready(until):
            return []
        kinds = np.fromiter((k for k, _ in self._pulses), dtype=np.int8, count=len(self._pulses))
        ticks = np.fromiter((t for _, t in self._pulses), dtype=np.int64, count=len(self._pulses))
        known = None
        if self._imu:
            rate = self.settings.imu_rate_hz
            known = KnownAccel.build(
                self._imu_t0, 1.0 / rate, np.asarray(self._imu), np.asarray(self._drive), self.damping
            )
        res = process(
            clean(kinds, ticks, self.tick_s),
            self.phi,
            self.gamma,
            self.settings,
            known,
            compensate=self.compensate and known is not None,
        )
        new = res.cloud.select((res.cloud.t > self._last_sent) & (res.cloud.t <= until))
        # What the data allowed is settled: points dropped now (anomalies, gaps) stay dropped.
        while self._pending and self._pending[0] <= until:
            self._pending.popleft()
        if len(new):
            self._last_sent = float(new.t[-1])
        return list(new.points())
