"""The SIL twins' bus on a real-time clock (the SIL devices' process): a combined transfer sleeps
its bit time once, then runs its messages; when each message acts must still be the wire's.

A stepping clock stands in for the real-time one (the bus treats any clock but a ManualClock as
real time), so each figure is arithmetic: the sleep moves time by exactly the bit time."""

from __future__ import annotations

import pytest

from tvsd.hw import imu_joint as joint
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050 import Mpu6050
from tvsd.sim.mpu6050 import sil_pair

S = ImuSettings()


class SteppingClock:
    """Real time's interface (not a ManualClock), advanced only by sleeps."""

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += max(seconds, 0.0)


def _both(clock: SteppingClock) -> list[Mpu6050]:
    bus, _ = sil_pair(S, clock, None, signal="counter", rate_errors={"pl": 0.0, "sa": 0.0})
    drivers = [Mpu6050(bus, n, S, clock.sleep) for n in ("pl", "sa")]
    for d in drivers:
        d.reset()
        d.configure()
    for d in drivers:
        d.reset_fifo()
    return drivers


def test_a_fifo_burst_pops_at_its_data_phase_not_at_the_transfers_end() -> None:
    """60 frames in each FIFO (1 kHz, 85 fit): on the wire the first burst pops from ~0.1 ms
    into the transfer (60 frames then), the second from ~16 ms (76): neither overflows. Popped
    at the transfer's end (~33 ms: 93 frames) both did, and the reader threw both reads away."""
    clock = SteppingClock()
    drivers = _both(clock)
    clock.sleep(0.0585)  # the resets and the count read add ~2 ms
    frames = [c // reg.FRAME_BYTES for c in joint.read_counts(drivers)]
    assert all(59 <= f <= 61 for f in frames), frames
    t0 = clock.now()
    out: list[list] = [[], []]
    overflow = joint.read_fifos(drivers, frames, out)
    bits = sum(27 + 9 * reg.FRAME_BYTES * f + 2 + 27 + 9 + 2 for f in frames)  # burst + INT_STATUS
    assert clock.now() - t0 == pytest.approx(bits / joint.BUS_HZ)  # ~33 ms: slept once, first
    assert overflow == [False, False]
    assert [sum(len(a) for a in o) for o in out] == frames


def test_a_burst_that_starts_past_the_fifo_overflows_as_on_the_wire() -> None:
    """The second sensor's burst starts after the first one's bytes: 80 frames each, the
    second pops ~22 ms in, its FIFO past 85 frames by then: that one overflows, on the chip too."""
    clock = SteppingClock()
    drivers = _both(clock)
    clock.sleep(0.0785)
    frames = [c // reg.FRAME_BYTES for c in joint.read_counts(drivers)]
    assert all(79 <= f <= 81 for f in frames), frames
    assert joint.read_fifos(drivers, frames, [[], []]) == [False, True]


def test_a_count_in_a_combined_transfer_is_latched_at_its_end() -> None:
    """FIFO_COUNT reads still see the frames up to the transfer's end (the reader's count times
    are upper bounds taken from the reply): tight, however long the transfer slept."""
    clock = SteppingClock()
    drivers = _both(clock)
    twins = [d.bus.devices[d.address] for d in drivers]  # type: ignore[attr-defined]
    clock.sleep(0.0205)
    t_end = clock.now() + 2 * joint.COUNT_BITS / joint.BUS_HZ
    counts = joint.read_counts(drivers)
    assert clock.now() == pytest.approx(t_end)
    for twin, count in zip(twins, counts, strict=True):
        twin.update(t_end)  # every frame due by the end: none is missing from the count
        assert count == len(twin.fifo) > 20 * reg.FRAME_BYTES


def test_the_bus_threads_timing_splits_service_into_bit_time_cpu_and_waits() -> None:
    """TimedBus (the SIL bus thread's handler, `soak_sil_bus` and `bench --only imu_sil`): the
    bit time is the bus's own count of bits at 400 kHz; the service holds at least that (the
    transfer sleeps it); the p99 is the upper edge of its 0.1 ms bin."""
    from tvsd.hw import i2c_remote as wire
    from tvsd.hw.imu_clock import MonotonicClock
    from tvsd.sim.bus_timing import BIN_MS, TimedBus

    bus, _ = sil_pair(S, MonotonicClock(), None, signal="counter")
    timed = TimedBus(wire.BusHandler(bus))
    addr = S.addresses["pl"]
    payload = wire.MESSAGE.pack(addr, 0, 1) + bytes([reg.WHO_AM_I]) + wire.MESSAGE.pack(addr, 1, 200)
    for _ in range(5):
        timed(wire.OP_RDWR, payload)
    got = timed.report()
    bit_ms = 1e3 * (27 + 9 * 200 + 2) / 400e3  # one [register] + read of 200 bytes: 4.6 ms
    assert got["requests"] == 5 and got["bit_time_mean_ms"] == pytest.approx(bit_ms, abs=1e-3)
    assert got["service_mean_ms"] >= bit_ms and got["excess_mean_ms"] >= 0.0
    assert got["service_p99_ms"] >= got["service_max_ms"] - BIN_MS
    # a sleep takes no CPU: the thread's CPU fits in what is not bit time (a bin for the clocks'
    # rounding: thread_time and monotonic are read apart)
    assert 0.0 < got["cpu_mean_ms"] <= got["service_mean_ms"] - bit_ms + BIN_MS
