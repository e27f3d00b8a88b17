"""SA IMU batches → the point stream's known acceleration (PointStream.add_samples), in MCU time.

The point stream compensates the SA speed's fluctuation between pulses with what is known of the
shaft's acceleration (tvsd.scan.compensation): the disturbance the SA IMU measures and the
drive model's acceleration of the commanded voltage, both as cell means on a uniform grid of
1/imu_rate_hz in MCU time, contiguous. This adapter makes that grid from what the daemon has:

- the SA gyro about the shaft axis, differentiated (Savitzky–Golay, tvsd.hw.angular_acceleration: the same
  filter as offline, its rate scaled by the batch's fitted sample rate, so a sensor clock a few %
  off does not scale α) and restarted at every gap or new FIFO epoch;
- sample times moved to MCU time by the daemon's host → MCU mapping (affine: the link's clock
  sync; applied to each batch's ends), minus the DLPF's delay (the reader leaves it in);
- α linearly interpolated to each cell's centre (the DLPF keeps α below ~190 Hz, so a centre
  value is the cell mean to ~0.3 % at 25 Hz); cells where no two samples less than `max_gap_s`
  apart bracket the centre (a lost stretch, a FIFO resync) get α = 0: uncompensated there,
  never stalled;
- the drive part: the commanded voltage sampled `sub` times per cell, through the current's lag
  L/R (exact for a command held over each sub-step, state kept across cells) and averaged:
  DriveModel.accel run as a stream.

`push(batch)` returns the points the stream could complete with the new cells. `advance(t_mcu)`
emits α = 0 cells up to an MCU time, for when the IMU is lost (the daemon's on_state): a
compensating stream waits for IMU data past each pulse, and must not wait forever.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np
from scipy.signal import lfilter

from tvsd.hw.angular_acceleration import SG_HALF, AngularAccelerationStream
from tvsd.hw.imu_sensor_reader import ImuBatch
from tvsd.scan.compensation import DriveModel
from tvsd.scan.points import Point

VoltageHistory = Callable[[np.ndarray], np.ndarray]  # MCU times (s) → commanded voltage (V)
HostToMcu = Callable[[float], float]  # host time (time.monotonic, s) → MCU time (s); NaN: not yet


class SampleSink(Protocol):
    """tvsd.scan.stream.PointStream's input side."""

    def add_samples(self, t0: float, imu: np.ndarray, drive: np.ndarray) -> list[Point]: ...


class ImuFeed:
    """Feeds one PointStream from the SA sensor's batches (the PL sensor's are ignored)."""

    def __init__(
        self,
        stream: SampleSink,
        to_mcu: HostToMcu,
        voltage: VoltageHistory,
        drive: DriveModel,
        *,
        rate_hz: float,
        axis: int,
        delay_s: float,
        sign: float = 1.0,
        max_gap_s: float = 0.005,
        sub: int = 10,
    ) -> None:
        """`rate_hz`: the stream's grid (ScanSettings.imu_rate_hz); `axis`: the SA axis index
        (imu_settings.SA_AXES[settings.sa_axis]); `delay_s`: the DLPF's (mpu6050_registers.DLPF_DELAY_S);
        `sign`: +1 if the gyro's positive sense about that axis is the shaft's."""
        self.stream, self.to_mcu, self.voltage, self.drive = stream, to_mcu, voltage, drive
        self.dt = 1.0 / rate_hz
        self.axis, self.delay_s, self.sign = axis, delay_s, sign
        self.max_gap_s, self.sub = max_gap_s, sub
        self._diff = AngularAccelerationStream(1.0)  # per sample; × the batch's rate
        self._tail_t = np.zeros(0)  # MCU times of the samples the differentiator holds
        self._k_next: int | None = None  # the next sample number expected (else: a gap)
        self._epoch = -1
        self._t = np.zeros(0)  # α samples not yet passed by the grid: MCU times, values, and
        self._a = np.zeros(0)
        self._joined = np.zeros(0, dtype=bool)  # whether each may be interpolated from the one before
        self._restart = True  # the next α sample starts a new segment
        self.t0 = math.nan  # the grid: cell c covers [t0 + c·dt, t0 + (c+1)·dt)
        self.cells = 0  # cells handed to the stream
        self.zero_cells = 0  # of which without IMU data (α = 0)
        self._current = 0.0  # the drive model's current lag state (its "end" value), V

    # --- input ---------------------------------------------------------------------------------
    def push(self, batch: ImuBatch) -> list[Point]:
        """One reader batch (any sensor; only "sa" is used); returns the points completed."""
        if batch.sensor != "sa" or len(batch.k) == 0:
            return []
        h0, h1 = float(batch.t[0]), float(batch.t[-1])
        m0, m1 = self.to_mcu(h0), self.to_mcu(h1)
        if not (math.isfinite(m0) and math.isfinite(m1)):  # no clock sync yet: cannot place
            self._gap()
            return []
        n = len(batch.k)
        if n > 1:
            tau = m0 + (batch.t - h0) * ((m1 - m0) / (h1 - h0)) - self.delay_s
            fs = (n - 1) / (h1 - h0)
        else:
            tau = np.array([m0 - self.delay_s])
            fs = 1.0 / self.dt
        if batch.epoch != self._epoch or self._k_next is None or int(batch.k[0]) != self._k_next:
            self._gap()
        self._epoch, self._k_next = batch.epoch, int(batch.k[-1]) + 1
        rate = self.sign * np.asarray(batch.gyro, dtype=np.float64)[:, self.axis]
        alpha = self._diff.push(rate) * fs
        times = np.concatenate([self._tail_t, tau])
        self._tail_t = times[-2 * SG_HALF :]
        if alpha.size:
            self._add(times[SG_HALF : SG_HALF + alpha.size], alpha)
        if math.isnan(self.t0) and self._t.size:
            self.t0 = float(self._t[0])
        if self._t.size == 0:
            return []
        # cells whose centre is at or before the newest α sample
        last = math.floor((self._t[-1] - self.t0) / self.dt - 0.5)
        return self._emit(last + 1 - self.cells)

    def advance(self, t_mcu: float) -> list[Point]:
        """Cells up to MCU time `t_mcu` (α = 0 where no IMU data came): for a lost IMU."""
        if not math.isfinite(t_mcu):
            return []
        if math.isnan(self.t0):
            self.t0 = t_mcu  # no IMU yet: the grid starts here
            return []
        return self._emit(math.floor((t_mcu - self.t0) / self.dt + 1e-6) - self.cells)

    def _gap(self) -> None:
        self._diff.reset()
        self._tail_t = np.zeros(0)
        self._restart = True

    def _add(self, t: np.ndarray, a: np.ndarray) -> None:
        joined = np.ones(t.size, dtype=bool)
        joined[0] = not self._restart
        self._restart = False
        self._t = np.concatenate([self._t, t])
        self._a = np.concatenate([self._a, a])
        self._joined = np.concatenate([self._joined, joined])

    # --- output --------------------------------------------------------------------------------
    def _emit(self, count: int) -> list[Point]:
        points: list[Point] = []
        if count > 0:
            start = self.t0 + self.cells * self.dt
            centres = start + (np.arange(count) + 0.5) * self.dt
            imu = self._alpha_at(centres)
            drive = self._drive(start, count)
            self.cells += count
            self.zero_cells += int(np.count_nonzero(imu == 0.0))
            points = self.stream.add_samples(start, imu, drive)
        # keep the samples the next centres may still need: from the one before the next centre
        keep = max(int(np.searchsorted(self._t, self.t0 + (self.cells + 0.5) * self.dt)) - 1, 0)
        self._t, self._a, self._joined = self._t[keep:], self._a[keep:], self._joined[keep:]
        return points

    def _alpha_at(self, centres: np.ndarray) -> np.ndarray:
        out = np.zeros(centres.size)
        if self._t.size < 2:
            return out
        i = np.searchsorted(self._t, centres)  # self._t[i-1] < centre <= self._t[i]
        ok = (i > 0) & (i < self._t.size)
        j = np.clip(i, 1, self._t.size - 1)
        t_lo, t_hi = self._t[j - 1], self._t[j]
        ok &= self._joined[j] & (t_hi - t_lo <= self.max_gap_s)
        w = np.clip((centres - t_lo) / np.maximum(t_hi - t_lo, 1e-12), 0.0, 1.0)
        value = self._a[j - 1] + w * (self._a[j] - self._a[j - 1])
        out[ok] = value[ok]
        return out

    def _drive(self, start: float, count: int) -> np.ndarray:
        """Mean drive acceleration over each cell: DriveModel.accel on `sub` steps per cell,
        with the current's lag state carried from the previous call."""
        h = self.dt / self.sub
        u = np.asarray(self.voltage(start + (np.arange(count * self.sub) + 0.5) * h), dtype=np.float64)
        tau = self.drive.tau_e
        if tau <= 0.0:
            mean = u
        else:
            decay = math.exp(-h / tau)  # first-order lag, exact for a command held over h
            end = lfilter([1.0 - decay], [1.0, -decay], u, zi=[decay * self._current])[0]
            start_vals = np.concatenate([[self._current], end[:-1]])
            self._current = float(end[-1])
            mean = u + (start_vals - u) * (tau / h) * (1.0 - decay)
        return self.drive.accel_per_volt * mean.reshape(count, self.sub).mean(axis=1)
