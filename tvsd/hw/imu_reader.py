"""IMU reader: drains both MPU6050 FIFOs in one thread (ImuReader), survives the bus, counts every
loss. Each sensor's poll, its policy and its accounting are SensorReader's (imu_sensor_reader.py);
a poll of both sensors together, tvsd.hw.imu_joint's.

The loop never dies: an unexpected exception is recorded and backed off like a bus error. The
thread hands batches to a callback (use asyncio_sink for an event loop).
"""

from __future__ import annotations

import asyncio
import logging
import os
import threading
from collections.abc import Callable

from tvsd.hw import heap
from tvsd.hw import imu_joint as joint
from tvsd.hw.imu_clock import Clock, MonotonicClock
from tvsd.hw.imu_sensor_reader import ImuBatch, SensorReader
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050 import Mpu6050, SMBusLike

log = logging.getLogger(__name__)
# SCHED_FIFO priority of the reader thread when the daemon runs --realtime: above the event loop
# and the threads it starts (40: it holds the GIL for whole RPC replies, and one hogged a core in
# the soak), below the MCU link's I/O thread (60) and the control thread (80). The FIFO holds
# 83 ms at 1 kHz: the reader may wait for the GIL, never for the loop's turn on the CPU.
READER_PRIORITY = 50
WAKE_LATE_S = 0.02  # a wake-up this late is counted (ImuReader.wake_late): a poll interval
# The reader thread's arena, grown and touched once at its start (tvsd.hw.heap.reserve, after
# the daemon's heap.tune()): its polls then allocate from memory already mapped, and never wait
# for the memory-map lock while they hold the GIL (453 ms once: docs/measurements/daemonfix.md §4;
# held by khugepaged for 100 ms in a soak: docs/measurements/imureader.md). Left as glibc sets it,
# its heap grew by ~1 MiB in 135 s of soak (84 mprotect calls; its blocks freed on the event
# loop's thread are reused there): 16 MiB is ~40 min of that growth.
HEAP_RESERVE_BYTES = 16 << 20


def asyncio_sink(
    loop: asyncio.AbstractEventLoop, queue: asyncio.Queue[ImuBatch]
) -> Callable[[ImuBatch], None]:
    """A callback that hands batches from the reader thread to an asyncio queue."""

    def sink(batch: ImuBatch) -> None:
        loop.call_soon_threadsafe(queue.put_nowait, batch)

    return sink


class ImuReader:
    """Polls its sensors in turn (one bus: transfers are serial anyway), in a thread or inline."""

    def __init__(
        self,
        sensors: list[SensorReader],
        clock: Clock,
        on_batch: Callable[[ImuBatch], None] | None = None,
        on_poll: Callable[[SensorReader], None] | None = None,
    ) -> None:
        """`on_batch(batch)` for each delivered batch, `on_poll(sensor)` after each sensor's turn
        (data or not: a sensor gone for good still has a state and a growing loss), both on the
        polling thread."""
        self.sensors, self.clock, self.on_batch, self.on_poll = sensors, clock, on_batch, on_poll
        self.priority: int | None = None  # SCHED_FIFO for the thread (start()), if set
        self.heap_reserve = 0  # bytes of arena the thread grows first (tvsd.hw.heap.reserve)
        self.heap_reserved = False  # whether it did
        self.started = threading.Event()  # set by the thread before its first poll
        self.realtime = "not requested"  # what the OS said to it
        self._stop = threading.Event()
        self._lock = threading.Lock()  # status() may come from another thread than the polls
        self._thread: threading.Thread | None = None
        self.joint = True  # poll all sensors together when they allow it (tvsd.hw.imu_joint)
        self.joint_polls = 0
        self.joint_gap_max_s = 0.0  # count transfer's return to the FIFO transfer's start, longest
        # the thread's wake-ups after its sleeps: how late (the CPU, the GIL: not the bus)
        self.wake_late_max_s = 0.0
        self.wake_late = 0  # over WAKE_LATE_S

    def step(self) -> list[ImuBatch]:
        """Poll every sensor that is due; never raises for device trouble. All plain polls
        (SensorReader.plain) go together (tvsd.hw.imu_joint), else each sensor polls alone."""
        out: list[ImuBatch] = []
        polled: list[SensorReader] = []
        if joint.possible(self):
            try:
                with self._lock:
                    polled = joint.poll(self)
            except Exception as exc:  # a bug must not kill the reader: record it, back off
                log.exception("IMU reader error (joint poll)")
                for sensor in self.sensors:
                    sensor._failed(f"internal error: {type(exc).__name__}: {exc}")
                polled = list(self.sensors)
        for sensor in self.sensors:
            if sensor in polled:
                batches = sensor.take()
            else:
                try:
                    with self._lock:
                        batches = sensor.poll()
                except Exception as exc:  # a bug must not kill the reader: record it, back off
                    log.exception("%s IMU reader error", sensor.name)
                    sensor._failed(f"internal error: {type(exc).__name__}: {exc}")
                    continue
            out.extend(batches)
            if self.on_batch is not None:
                for batch in batches:
                    self.on_batch(batch)
            if self.on_poll is not None:
                self.on_poll(sensor)
        return out

    def _wait(self) -> None:
        due = min(s.next_time for s in self.sensors)
        now = self.clock.now()
        asked = max(due - now, 0.0005)
        self.clock.sleep(asked)
        late = self.clock.now() - now - asked
        if late > self.wake_late_max_s:
            self.wake_late_max_s = late
        if late > WAKE_LATE_S:
            self.wake_late += 1

    def run_for(self, seconds: float) -> list[ImuBatch]:
        """Run inline until `seconds` of clock time have passed (simulated or real)."""
        end = self.clock.now() + seconds
        out: list[ImuBatch] = []
        while self.clock.now() < end:
            out.extend(self.step())
            self._wait()
        return out

    def start(self) -> None:
        self._stop.clear()
        self.started.clear()
        self._thread = threading.Thread(target=self._run, name="imu-reader", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self.priority is not None:
            try:  # pid 0: this thread
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(self.priority))
                self.realtime = f"granted (priority {self.priority})"
            except OSError as exc:
                self.realtime = f"refused: {exc.strerror or exc}"
                log.warning("IMU reader thread SCHED_FIFO %s", self.realtime)
        if self.heap_reserve:  # 16 MiB: 20-330 ms of page faults on this thread, before any poll
            self.heap_reserved = heap.reserve(self.heap_reserve)
        self.started.set()
        while not self._stop.is_set():
            self.step()
            self._wait()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def status(self) -> dict[str, dict[str, object]]:
        """Per sensor: state (starting/ok/degraded), chip, fitted rate, counters, last error."""
        with self._lock:
            return {s.name: s.status() for s in self.sensors}


def make_reader(
    bus: SMBusLike,
    settings: ImuSettings,
    clock: Clock | None = None,
    on_batch: Callable[[ImuBatch], None] | None = None,
) -> ImuReader:
    """Both sensors' reader, with the calibration file applied if there is one (at start).

    No file: a warning, and the raw gyro. A damaged file: DataFileError (the caller decides
    whether that stops the daemon or only the IMU part).
    """
    from tvsd.hw import imu_calibration

    clock = clock or MonotonicClock()
    calib = imu_calibration.load_or_none(settings.calibration_file)
    if calib is None:
        log.warning("no IMU calibration at %s: gyro bias not removed", settings.calibration_file)
    readers = [
        SensorReader(
            Mpu6050(bus, name, settings, clock.sleep),
            clock,
            None if calib is None or name not in calib else calib[name].gyro_bias_rad_s,
        )
        for name in ("pl", "sa")
    ]
    return ImuReader(readers, clock, on_batch)
