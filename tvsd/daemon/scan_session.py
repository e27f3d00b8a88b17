"""A scan in progress, and the counts of the points the daemon has published.

`ScanSession` owns the point stream at one aim and, while the IMU is healthy, the feed of its SA
acceleration into that stream (tvsd.daemon.imu_feed): compensated points, else points from the
zero pulses alone, flagged no_imu. A new aim or a change in the IMU's health means a new session
(the pulses of the revolution in progress are dropped). `PointCounters` outlives the sessions:
the status's `points` block.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from tvsd.config import Config
from tvsd.daemon.imu_feed import ImuFeed
from tvsd.daemon.status import PointsStatus
from tvsd.hw.imu_settings import SA_AXES
from tvsd.hw.mpu6050_registers import DLPF_DELAY_S
from tvsd.scan.compensation import DriveModel
from tvsd.scan.points import FLAG_NO_IMU, Point
from tvsd.scan.stream import PointStream

RATE_WINDOW_S = 2.0  # points/s is counted over this long
LATENCY_KEPT = 500  # optical pulse → point published, for the status's p50 and max


class ScanSession:
    """The point stream at aim (φ, γ in degrees); compensated when `compensate` (the IMU is ok)."""

    def __init__(
        self,
        cfg: Config,
        aim_deg: tuple[float, float],
        clock_hz: float,
        *,
        compensate: bool,
        to_mcu_s: Callable[[float], float],
        sent_volts: Callable[[np.ndarray], np.ndarray],
    ) -> None:
        self.aim_deg = aim_deg
        phi, gamma = (math.radians(v) for v in aim_deg)
        p = cfg.plant
        model = DriveModel.from_plant(p.kM, p.ku, p.R, p.J, p.kv + p.sigma2, p.kb, p.L)
        self.stream = PointStream(
            cfg.scan, phi, gamma, 1.0 / clock_hz, compensate=compensate, damping=model.damping
        )
        self.feed: ImuFeed | None = None
        if compensate:
            imu = cfg.imu
            self.feed = ImuFeed(
                self.stream,
                to_mcu_s,
                sent_volts,
                model,
                rate_hz=cfg.scan.imu_rate_hz,
                axis=SA_AXES[imu.sa_axis],
                delay_s=DLPF_DELAY_S.get(imu.dlpf_cfg, 0.0),
            )

    @property
    def compensated(self) -> bool:
        return self.feed is not None

    def pulse(self, channel: int, mcu_ticks: int) -> list[Point]:
        """One pulse from the MCU; the points it completes."""
        return self.stream.add_pulse(channel, mcu_ticks)

    def imu_batch(self, batch: Any) -> list[Point]:
        """One IMU reader batch (tvsd.hw.imu_sensor_reader.ImuBatch); the points it completes."""
        return self.feed.push(batch) if self.feed is not None else []


class PointCounters:
    """Points published since the daemon started."""

    def __init__(self) -> None:
        self.total = 0
        self.no_imu = 0
        self._window: deque[tuple[float, int]] = deque()  # (time of an optical pulse, total then)
        self._latency: deque[float] = deque(maxlen=LATENCY_KEPT)  # s

    def optical_pulse(self) -> None:
        self._window.append((time.monotonic(), self.total))

    def published(self, point: Point) -> None:
        if point.flags & FLAG_NO_IMU:
            self.no_imu += 1
        if math.isfinite(point.t_mono):
            self._latency.append(time.monotonic() - point.t_mono)
        self.total += 1

    def per_s(self) -> float:
        w = self._window
        now = time.monotonic()
        while w and now - w[0][0] > RATE_WINDOW_S:
            w.popleft()
        if len(w) < 2 or w[-1][0] == w[0][0]:
            return 0.0
        return (w[-1][1] - w[0][1]) / (w[-1][0] - w[0][0])

    def status(self) -> PointsStatus:
        per_s = self.per_s()
        if not self._latency:
            return PointsStatus(self.total, self.no_imu, per_s)
        lat = np.asarray(self._latency) * 1e3
        return PointsStatus(self.total, self.no_imu, per_s, float(np.median(lat)), float(lat.max()))
