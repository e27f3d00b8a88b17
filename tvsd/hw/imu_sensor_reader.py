"""One MPU6050's FIFO poll (SensorReader): bring-up, sample numbers and times, every loss counted.

Policy lives here, mechanism in mpu6050.py. Per sensor, each poll reads FIFO_COUNT, the whole frames
present, then INT_STATUS (in the frames' last combined transfer: two round trips a poll; both
sensors' plain polls share their two, tvsd.hw.imu_joint). Frames are held as *pending* until that
status read says no overflow happened while they sat in the FIFO (an overflow drops the oldest bytes
and misaligns what follows); then they are delivered. A byte count that is not a whole number of
frames also means misalignment (a failed transfer that popped part of a frame); so does any failed
FIFO transfer but a NACK (it may have popped whole frames, which no count reveals). All end in a
*resync*: FIFO reset, and a new epoch whose first sample number is estimated from the fitted sensor
clock, so the gap is counted as lost samples. The sensor has no sample counter: without resyncs the
count is exact; with them it is as good as the clock fit (SensorReader.lost refines it as the fit
matures; the property tests bound it by the rate error times the span, +-1). Samples after the
newest delivered one count as lost as soon as they can no longer arrive (SensorReader.overdue): the
FIFO overflowed (more than its 85 frames since) or was reset; a sensor gone for good thus counts its
samples by its rate and the time elapsed, and when it comes back the new epoch's gap takes them over
(the same samples, never twice).

Sample numbers and times: within an epoch the k-th frame is sample k_start + k. The sensor clock
(a few % off nominal) is fitted against host read times: the rate by least squares with outlier
rejection (ClockFit.rate), each epoch's phase by the lower envelope of t - K/rate (ClockFit.t0;
K = newest sample number at host time t, so K = floor(rate·(t - t0))). A sample's time is
t0 + k/rate: when it entered the FIFO (the DLPF's delay, mpu6050_registers.DLPF_DELAY_S, is not
removed).

Failures: every bus error is counted, retried after an exponential back-off (5 ms doubling to
0.5 s), and after two in a row the sensor is "degraded"; a sensor found reset or asleep after a
failure is brought up again. The thread that polls the sensors in turn is ImuReader (imu_reader.py).
"""

from __future__ import annotations

import errno
import logging
from dataclasses import dataclass

import numpy as np

from tvsd.errors import DeviceError
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.imu_clock import Clock, ClockFit
from tvsd.hw.imu_settings import ImuSettings, to_si
from tvsd.hw.mpu6050 import Mpu6050

log = logging.getLogger(__name__)
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.005, 0.5
FIFO_FRAMES = reg.FIFO_SIZE // reg.FRAME_BYTES  # 85: more samples than this unread overflow it


@dataclass(frozen=True)
class ImuBatch:
    """One sensor's newly confirmed samples of one epoch (SensorReader.poll, ImuReader's callback)."""

    sensor: str
    k: np.ndarray  # sample numbers (int64); a jump is a counted loss
    epoch: int
    t: np.ndarray  # s, host monotonic time base, from the clock fit at delivery
    accel: np.ndarray  # (n, 3) m/s^2
    gyro: np.ndarray  # (n, 3) rad/s, calibration bias removed
    raw: np.ndarray  # (n, 6) int16 as read


class SensorReader:
    """One sensor's poll state machine. Call poll() from the reader thread only."""

    def __init__(
        self,
        driver: Mpu6050,
        clock: Clock,
        gyro_bias: np.ndarray | tuple[float, float, float] | None = None,
    ) -> None:
        self.driver, self.clock = driver, clock
        self.name = driver.name
        self.settings: ImuSettings = driver.settings
        self.gyro_bias = np.zeros(3) if gyro_bias is None else np.asarray(gyro_bias, float)
        self.fit = ClockFit(self.settings.sample_rate_hz)
        self.up = False
        self.chip = ""
        self.state = "starting"
        self.samples = self.errors = self.overflows = self.resyncs = self.restarts = 0
        self._gaps = 0  # samples skipped at epoch starts, as first estimated
        self._open_gap = 0  # the gap before the current epoch, until an epoch delivers
        self._first_epoch = self._delivered_epoch = 0  # first and latest that delivered
        self.last_error = ""
        self.epoch = -1
        self.k_next = 0
        self._epoch_open = False  # the next count read fixes the epoch's first sample number
        self._pending: list[np.ndarray] = []  # frames read, not yet vouched for by INT_STATUS
        self._ready: list[ImuBatch] = []
        self._need_resync = False
        self._stage = "reset"  # bring-up stage: reset, configure, start
        self._wait_s = 0.0
        self._check_running = False
        self._failures = 0
        self.next_time = 0.0
        self._last_data = 0.0
        self._newest: tuple[int, int] | None = None  # (k, epoch) of the newest delivered sample
        self._cut_t = -np.inf  # host time of the latest FIFO reset (what it held is gone)
        # timing of the reads (status): the longest gap between two FIFO count reads, how many
        # were longer than the FIFO holds (it may have overflowed: the reader was late), the
        # fullest FIFO seen, the longest poll (count read to status read: bus time)
        self._t_count = np.nan
        self.gap_max_s = self.poll_max_s = 0.0
        self.late_polls = self.fifo_peak = 0

    def status(self) -> dict[str, object]:
        return {
            "state": self.state,
            "chip": self.chip,
            "rate_hz": self.fit.rate(),
            "rate_sigma_hz": self.fit.rate_stderr,
            "samples": self.samples,
            "lost": self.lost,
            "errors": self.errors,
            "overflows": self.overflows,
            "resyncs": self.resyncs,
            "restarts": self.restarts,
            "last_error": self.last_error,
            "poll_gap_max_ms": round(1e3 * self.gap_max_s, 2),
            "late_polls": self.late_polls,
            "fifo_peak_frames": self.fifo_peak,
            "poll_max_ms": round(1e3 * self.poll_max_s, 2),
        }

    def poll(self) -> list[ImuBatch]:
        """One attempt if due; returns the newly confirmed samples (one batch per epoch)."""
        if self.clock.now() < self.next_time:
            return []
        try:
            self._poll()
        except DeviceError as exc:
            self._failed(str(exc))
        else:
            self._ok()
        return self.take()

    def take(self) -> list[ImuBatch]:
        """The batches confirmed since the last call."""
        ready, self._ready = self._ready, []
        return ready

    def _ok(self) -> None:
        """After a good poll: healthy, and the next one scheduled."""
        self._failures = 0
        if self.up:
            self.state = "ok"
        self.next_time = self._next_due()

    def plain(self) -> bool:
        """Whether the next poll is a plain one (FIFO_COUNT, the frames, INT_STATUS) that may
        share its transfers with the other sensor's (tvsd.hw.imu_joint): running, healthy,
        nothing to recover or check first. A sensor without data for a while is checked (is it
        still running?) when its count read finds nothing (tvsd.hw.imu_joint): a FIFO that fills
        says so, and a check on every poll of a reader behind its FIFO slowed it further."""
        return self.up and not self._failures and not self._need_resync and not self._check_running

    def _stale(self) -> bool:
        return self.clock.now() - self._last_data > 5 * self.settings.poll_interval_s

    def _next_due(self) -> float:
        """After a good poll: a bring-up stage's wait from now; else the next poll at a fixed
        rate, one interval after this one was due, so the polls' bus time does not stretch the
        period (at 1 kHz the frames take ~30 % of a 400 kHz bus per sensor: mpu6050.bus_budget; waiting
        a whole interval after each poll made the period 29 ms, 35 % of the FIFO's 83 ms).
        Late (the poll took longer than the interval): at once, the schedule from now."""
        now = self.clock.now()
        if self._wait_s:
            wait, self._wait_s = self._wait_s, 0.0
            return now + wait
        due = self.next_time + self.settings.poll_interval_s
        return due if due > now else now

    def _failed(self, message: str) -> None:
        if not self.up:
            self._stage = "reset"  # a bring-up that failed half-way starts again
        self.errors += 1
        self._failures += 1
        self.last_error = message
        self._check_running = True
        if self._failures >= 2 or not self.up:
            if self.state != "degraded":
                log.warning("%s IMU degraded: %s", self.name, message)
            self.state = "degraded"
        backoff = min(BACKOFF_MIN_S * 2 ** (self._failures - 1), BACKOFF_MAX_S)
        self.next_time = self.clock.now() + backoff

    def _bring_up(self) -> bool:
        """One stage of the bring-up; True once running. Waits are scheduled, not slept, so
        the other sensor keeps being drained meanwhile (its FIFO holds only 85 ms)."""
        if self._stage == "reset":
            self.chip = self.driver.probe()
            self.driver.reset()
            self._stage, self._wait_s = "configure", reg.RESET_S
        elif self._stage == "configure":
            self.driver.configure()
            self._stage, self._wait_s = "start", reg.GYRO_STARTUP_S
        else:
            self.driver.reset_fifo()  # drop the samples of the gyro's start-up
            self._cut_t = self.clock.now()
            self._stage, self.up = "reset", True
            self._pending.clear()
            self._new_epoch()
        return self.up

    @property
    def lost(self) -> int:
        """Samples the sensor took since the first delivered that never arrived and never will:
        the gaps between delivered samples (`gaps_lost`) and the tail after the newest one that
        can no longer arrive (`overdue`). A tail is counted by one of them only: a new epoch's
        gap is counted once the epoch delivers, which makes the newest delivered sample newer
        than the tail it replaces."""
        return self.gaps_lost + self.overdue(self.clock.now())

    @property
    def gaps_lost(self) -> int:
        """Samples the sensor took between the first and the last delivered, not delivered.

        A gap is first estimated when its epoch opens, from a clock fit that may still be young.
        An error of d samples there shows up later as a step of d/rate between the phases the
        fit finds for the epochs (the oscillator ran on). Summed over all gaps these steps
        telescope: the total error is the phase of the last epoch against the first, in whole
        periods, so short epochs with poorly known phases do not matter. (After a power cycle
        the phase restarts and a gap is the nearest whole number of periods.)
        """
        tails = self.fit.tails
        first, last = max(self._first_epoch, min(tails, default=0)), self._delivered_epoch
        if first >= last or last not in tails or first not in tails:
            return self._gaps + self.fit.dropped_fix
        rate = self.fit.rate()
        step = round((self.fit.t0(last, rate) - self.fit.t0(first, rate)) * rate)
        return self._gaps + self.fit.dropped_fix + step

    def overdue(self, now: float) -> int:
        """Samples taken after the newest delivered one, up to `now`, that can no longer arrive:
        those before a FIFO reset since (it emptied the FIFO), and, once more have come than the
        FIFO holds (85 frames), all those after it too (an overflow drops the oldest bytes and
        misaligns the rest: the reader discards the lot when it reads it). Fewer may still be
        read: not lost yet. By the fitted clock on the newest delivered sample's epoch phase, so
        a sensor that never comes back counts its samples by its rate and the time elapsed."""
        if self._newest is None:
            return 0
        k, epoch = self._newest
        rate = self.fit.rate()
        t0 = self.fit.t0(epoch, rate)
        start = k
        before_cut = 0
        if self._cut_t > t0 + (k + 1) / rate:  # a reset after the newest delivered sample
            start = max(k, int(np.floor((self._cut_t - t0) * rate)))
            before_cut = start - k
        after = int(np.floor((now - t0) * rate)) - start
        return before_cut + (after if after > FIFO_FRAMES else 0)

    def _new_epoch(self) -> None:
        self._pending.clear()
        self._epoch_open = True
        self.epoch += 1
        self._last_data = self.clock.now()

    def _poll(self) -> None:
        if not self.up and not self._bring_up():
            return
        if self._need_resync:
            self._recover()
            return
        if self._check_running or self._stale():  # a sensor reset behind our back is asleep, FIFO off
            if not self.driver.is_running():
                log.warning("%s IMU was reset; configuring it again", self.name)
                self.restarts += 1
                self.up = False
                self._bring_up()
                return
            self._check_running = False
        count = self.driver.fifo_count()
        t_count = self.clock.now()  # after the read: see ClockFit.t0
        frames = self.counted(count, t_count)
        if frames is None:
            return
        # frames read before a failed transfer stay pending: every transfer is whole frames
        try:
            overflow = self.driver.read_frames_then_overflow(frames, self._pending)
        except DeviceError as exc:
            # No ACK to the address: nothing moved. Any other failure may have popped part of
            # the FIFO, maybe whole frames (which the count cannot reveal): start over aligned.
            if exc.errno not in (errno.ENXIO, errno.EREMOTEIO):
                self._need_resync = True
            raise
        self.read_done(overflow, t_count)

    def counted(self, count: int, t_count: float) -> int | None:
        """A FIFO_COUNT read (`count` bytes, the read done at `t_count`): the whole frames to read
        now, or None if the FIFO was misaligned (then recovered: bus I/O, may raise)."""
        frames = count // reg.FRAME_BYTES
        self._timing(t_count, frames)
        if count % reg.FRAME_BYTES:  # part of a frame went missing: the FIFO is misaligned
            self._recover()
            return None
        if self._epoch_open:
            self._open_epoch(t_count, frames)
        held = sum(len(p) for p in self._pending)
        if frames or held:
            self.fit.add(t_count, self.k_next + held + frames - 1, self.epoch)
        if frames:
            self._last_data = t_count
        return frames

    def read_done(self, overflow: bool, t_count: float) -> None:
        """The frames counted are pending, INT_STATUS read after them: deliver, or recover from
        an overflow (which misaligned what was read: all of it is discarded)."""
        if overflow:
            self._recover(overflow=True)
        else:
            self._deliver()
        self.poll_max_s = max(self.poll_max_s, self.clock.now() - t_count)

    def _timing(self, t_count: float, frames: int) -> None:
        gap = t_count - self._t_count  # NaN at the first read
        self._t_count = t_count
        self.fifo_peak = max(self.fifo_peak, frames)
        if gap > self.gap_max_s:
            self.gap_max_s = gap
        if gap > FIFO_FRAMES / self.settings.sample_rate_hz:
            self.late_polls += 1

    def _open_epoch(self, t_count: float, frames: int) -> None:
        if not self.samples or not self.fit.points:  # losses count from the first delivery
            first = self.k_next
        else:  # the sensor kept sampling during the gap: place us on its clock
            first = max(self.fit.newest_at(t_count) - frames + 1, self.k_next)
        # counted once an epoch delivers (losses run up to the last delivered sample); epochs
        # that never delivered add theirs to the next one's
        self._open_gap += first - self.k_next
        self.k_next = first
        self._epoch_open = False

    def _recover(self, overflow: bool | None = None) -> None:
        """Deliver what the status read vouches for, then restart the FIFO aligned (a resync).
        `overflow` None: INT_STATUS not read yet; it is, in the reset's own transfer, before
        the reset. If the reset fails, the next poll tries again (pending frames kept)."""
        self._need_resync = True  # stays set if the reset fails, so the next poll retries it
        flag = self.driver.reset_fifo(status_first=overflow is None)
        self._cut_t = self.clock.now()
        self._need_resync = False
        if overflow if overflow is not None else flag:
            self.overflows += 1
        else:
            self._deliver()
        self._pending.clear()
        self.resyncs += 1
        self._new_epoch()

    def _deliver(self) -> None:
        if not self._pending:
            return
        self._gaps += self._open_gap
        self._open_gap = 0
        if not self.samples:
            self._first_epoch = self.epoch
        self._delivered_epoch = self.epoch
        raw = np.concatenate(self._pending)
        self._pending.clear()
        k = np.arange(self.k_next, self.k_next + len(raw), dtype=np.int64)
        self.k_next += len(raw)
        self.samples += len(raw)
        accel, gyro = to_si(raw, self.settings)
        t = self.fit.times(k, self.epoch)
        self._newest = (int(k[-1]), self.epoch)
        self._ready.append(ImuBatch(self.name, k, self.epoch, t, accel, gyro - self.gyro_bias, raw))
