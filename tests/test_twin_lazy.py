"""The SIL IMU twins sample lazily: a FIFO_COUNT or INT_STATUS read makes no samples, the FIFO pop
makes them, caught up to the pop's time (tvsd.sim.mpu6050.SimMpu6050.read; issue 13, IMU loss).

Measured before (`tvsctl bench --only imu_sil`, docs/measurements/daemonfix.md): each read updated
the twin, 2.7-2.8 generations per bus request (a joint poll's count read, its burst and the
INT_STATUS after it, per sensor), and those generations were 0.58-0.65 ms of the SIL bus thread's
0.70-0.78 ms of CPU per request, nearly all fixed cost per call. What the reader sees must not
change: the same poll schedule gives the same counts, bytes and overflow flags as a twin updated
at every read (the counter signal numbers every sample, so any difference shows)."""

from __future__ import annotations

import numpy as np

from tvsd.hw import imu_joint as joint
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050 import Mpu6050
from tvsd.sim.i2c_bus import SimI2CBus
from tvsd.sim.mpu6050 import SimMpu6050

S = ImuSettings()
NAMES = ("pl", "sa")


class SteppingClock:
    """Real time's interface (not a ManualClock: the bus then runs as in the SIL process),
    advanced only by sleeps, so both rigs below see the same times."""

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(seconds, 0.0)


class EagerTwin(SimMpu6050):
    """The twin as it was: every read first takes the samples due by its time."""

    def read(self, register: int, length: int, partial: bool = False, now: float | None = None) -> list[int]:
        self.update(now)
        return super().read(register, length, partial, now)


def _rig(twin: type[SimMpu6050]) -> tuple[SteppingClock, list[Mpu6050], list[SimMpu6050]]:
    clock = SteppingClock()
    errors = {"pl": 0.027, "sa": -0.031}  # sil_pair's: two rates, neither nominal
    twins = [twin(None, clock, rate_error=errors[n], signal="counter", seed=i) for i, n in enumerate(NAMES)]
    bus = SimI2CBus(clock, {S.addresses[n]: d for n, d in zip(NAMES, twins, strict=True)}, bus_hz=400e3)
    drivers = [Mpu6050(bus, n, S, clock.sleep) for n in NAMES]
    for d in drivers:
        d.reset()
        d.configure()
    for d in drivers:
        d.reset_fifo()
    return clock, drivers, twins


def _poll(
    clock: SteppingClock, drivers: list[Mpu6050], gap_s: float
) -> tuple[list[int], list[bool], list[bytes]]:
    """One joint poll after `gap_s`: the counts, the overflow flags, the bytes popped."""
    clock.sleep(gap_s)
    frames = [min(c // reg.FRAME_BYTES, joint.MAX_BURST) for c in joint.read_counts(drivers)]
    out: list[list[np.ndarray]] = [[], []]
    overflow = joint.read_fifos(drivers, frames, out)
    return frames, overflow, [b"".join(a.astype(">i2").tobytes() for a in o) for o in out]


def test_a_poll_samples_once_per_sensor_at_its_pop_and_reads_what_an_eager_twin_gives() -> None:
    """Polls 5-120 ms apart (past 85 frames: overflows) on a lazy and an eager twin pair: every
    count, overflow flag and popped byte equal; the lazy pair samples once per sensor and poll
    without an overflow (the eager one 2-3 times: count read, burst, INT_STATUS)."""
    gaps = np.random.default_rng(3).uniform(0.005, 0.12, 60)
    lazy_clock, lazy_drivers, lazy = _rig(SimMpu6050)
    eager_clock, eager_drivers, eager = _rig(EagerTwin)
    gens_lazy, gens_eager, overflows = [], [], 0
    for gap in gaps:
        g0, e0 = [t.generations for t in lazy], [t.generations for t in eager]
        got = _poll(lazy_clock, lazy_drivers, gap)
        want = _poll(eager_clock, eager_drivers, gap)
        assert got == want
        assert lazy_clock.now() == eager_clock.now()
        overflows += sum(got[1])
        if not any(got[1]):
            gens_lazy += [t.generations - g for t, g in zip(lazy, g0, strict=True)]
            gens_eager += [t.generations - g for t, g in zip(eager, e0, strict=True)]
    assert overflows > 0  # the schedule reaches the overflow path too
    assert set(gens_lazy) == {1}, gens_lazy
    assert min(gens_eager) >= 2, gens_eager
    for a, b in zip(lazy, eager, strict=True):  # caught up, both took the same samples
        a.update(lazy_clock.now())
        b.update(eager_clock.now())
        assert a.sample_number == b.sample_number and a.produced == b.produced and a.fifo == b.fifo


def test_a_count_read_that_would_overflow_makes_the_samples_and_flags_it_once() -> None:
    """Past 1024 bytes the count read makes the frames (which bytes the overflow drops, and when,
    are the chip's): it reads the full FIFO, INT_STATUS says overflow once, then no more."""
    clock, drivers, twins = _rig(SimMpu6050)
    clock.sleep(0.2)  # ~200 frames due, 85 fit
    g0 = [t.generations for t in twins]
    assert joint.read_counts(drivers) == [reg.FIFO_SIZE, reg.FIFO_SIZE]
    assert [t.generations - g for t, g in zip(twins, g0, strict=True)] == [1, 1]
    status = [d.bus.read_byte_data(d.address, reg.INT_STATUS) for d in drivers]
    assert all(s & reg.INT_FIFO_OFLOW for s in status), status
    again = [d.bus.read_byte_data(d.address, reg.INT_STATUS) for d in drivers]
    assert not any(s & reg.INT_FIFO_OFLOW for s in again), again
