"""Property: under any fault schedule the reader survives, delivers only intact samples in order,
and samples out = samples in - counted losses: exactly when no gap had to be estimated, else to
the precision of the fitted sensor clock (the MPU6050 has no sample counter, so a gap's length
comes from the clock fit; see tvsd.hw.imu_sensor_reader and SensorReader.lost).

"Samples in" are all the sensor took from the first delivered one to the end of the run, less
those that can still arrive (at most a FIFO's worth since the newest delivered, no overflow, no
reset since). A sensor disconnected for good is in the schedules too: its missing samples count
as lost by its rate and the time elapsed (issue 13: it reported lost = 0 with 81 % missing).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from tvsd.hw.imu_clock import ManualClock
from tvsd.hw.imu_reader import ImuReader
from tvsd.hw.imu_sensor_reader import FIFO_FRAMES, SensorReader
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050 import Mpu6050
from tvsd.sim.i2c_bus import Fault
from tvsd.sim.mpu6050 import decode_counter, sil_pair

S = ImuSettings()
# power_cycle is left out: the part stops sampling while off, so there is no "sample in" to
# count; test_imu_reader covers its recovery.
KINDS = ["nack", "eio", "partial", "stall", "disconnect"]


FOREVER = math.inf
RUN_S, SETTLE_S = 4.0, 0.6


@st.composite
def fault(draw: st.DrawFn) -> Fault:
    start = draw(st.floats(0.3, 2.5))
    kind = draw(st.sampled_from(KINDS))
    # now and then a sensor (or both) unplugged for good
    forever = kind == "disconnect" and draw(st.booleans())
    return Fault(
        kind,
        start,
        FOREVER if forever else start + draw(st.floats(0.0005, 0.4)),
        draw(st.sampled_from([None, 0x68, 0x69])),
    )


faults = st.lists(fault(), max_size=4)


@pytest.mark.slow  # 40 runs of 4.6 s of simulated bus: 8-15 s on this shared machine
@example(  # found by a 300-example run: an epoch that never delivered, at the very end
    schedule=[
        Fault("stall", 2.0, 2.25, 0x69),
        Fault("nack", 1.75, 1.828125),
        Fault("nack", 0.5, 0.75, 0x69),
        Fault("stall", 0.9375, 1.125),
    ],
    error_rate=0.02,
    seed=41,
)
@example(  # the case the first try (a2d9d75) got wrong: NACKed past the FIFO, then back
    schedule=[Fault("nack", 1.0, 1.4, 0x69)], error_rate=0.0, seed=3
)
@example(schedule=[Fault("disconnect", 1.0, FOREVER, 0x69)], error_rate=0.0, seed=5)  # issue 13's
@example(schedule=[Fault("disconnect", 1.0, FOREVER, 0x69)], error_rate=0.02, seed=6)
@example(  # found in CI: a bring-up error, then both gone at 0.375 s: pl never delivered
    schedule=[Fault("disconnect", 0.375, FOREVER)], error_rate=0.02, seed=0
)
@settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(schedule=faults, error_rate=st.sampled_from([0.0, 0.002, 0.02]), seed=st.integers(0, 99))
def test_samples_out_equal_samples_in_minus_counted_losses(schedule, error_rate, seed):
    clock = ManualClock()
    bus, devs = sil_pair(S, clock, signal="counter", seed=seed)
    bus.faults = schedule
    bus.error_rate = error_rate
    readers = [SensorReader(Mpu6050(bus, n, S, clock.sleep), clock) for n in ("pl", "sa")]
    reader = ImuReader(readers, clock)
    batches = reader.run_for(RUN_S)  # faults end by 2.9 s (but those for good); back-off <= 0.5 s
    # then a clean bus for a while, so that each sensor that can deliver has, after any reset:
    # what it still holds is then at most a poll's worth, in a FIFO that will be read
    bus.error_rate = 0.0
    batches += reader.run_for(SETTLE_S)
    for r in readers:
        dev = devs[r.name]
        gone = any(f.end == FOREVER and f.address in (None, S.addresses[r.name]) for f in schedule)
        mine = [b for b in batches if b.sensor == r.name]
        if not mine:  # gone before its first batch (a bring-up error, then the disconnect): no
            # stream began, so there is no epoch to count losses from; it must say it is down
            assert gone and r.samples == 0 and r.state != "ok" and r.last_error, (r.state, r.last_error)
            continue
        raw = np.concatenate([b.raw for b in mine])
        k = np.concatenate([b.k for b in mine])
        n, ok = decode_counter(raw)
        assert ok.all(), "misaligned frame delivered"
        assert np.all(np.diff(n) > 0) and np.all(np.diff(k) > 0)
        dev.update()  # the twin takes the samples due by now (it samples lazily, on access)
        taken = dev.sample_number  # every sample taken since power-on, numbered from 0
        tail = taken - 1 - int(n[-1])  # taken after the newest delivered
        n_in, out = taken - int(n[0]) - (tail if tail <= FIFO_FRAMES else 0), len(n)
        assert out == r.samples
        if gone:  # most of the run missing, and counted (the old count said 0); by the fitted
            # rate, which before ~0.1 s of data is the nominal one: the twin's clock is up to 3 % off
            assert tail > FIFO_FRAMES and r.lost > 0.95 * tail
        if r.resyncs == 0 and not gone:  # no gap needed estimating: exact
            assert n_in - out == r.lost == 0
        else:
            # Gaps are measured on the fitted sensor clock: the total is the phase of the last
            # epoch against the first, in whole periods (+-1 rounding), and a rate error dr
            # misplaces it by dr*T over the span T. A clean bus fits the rate to ~0.01 Hz;
            # resyncs every ~0.1 s (2 % errors) leave epochs of a few reads: ~0.5 Hz. The fit
            # reports its standard error; the truth must lie within 4 of them. A sensor gone
            # for good: its tail is counted on the same fit from the newest delivered sample's
            # epoch phase (good to a fraction of a period: +-1 more) to the end of the run.
            rate_err = abs(r.fit.rate() - dev.rate_hz)
            assert rate_err < 4 * max(r.fit.rate_stderr, 0.005), (rate_err, r.fit.rate_stderr)
            span = (taken - 1 - n[0]) / dev.rate_hz
            bound = 1 + int(gone) + int(np.ceil(rate_err * span))
            assert abs(n_in - out - r.lost) <= bound, (n_in, out, r.lost, r.resyncs, bound)
            if error_rate == 0 and not gone:  # only bursts: few, long epochs, a rate good to
                # ~0.01 Hz (a sensor gone early may have had no time to fit it: the bound above)
                assert abs(n_in - out - r.lost) <= 1
        if gone:
            continue
        # and it came back, with samples from the last 0.3 s (with random errors still going on
        # until RUN_S, it came back on the clean bus after them)
        assert max(b.t[-1] for b in mine) > RUN_S + SETTLE_S - 0.3
        assert r.state == "ok", r.last_error
