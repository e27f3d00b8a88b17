"""Property: under any fault schedule the reader survives, delivers only intact samples in order,
and samples out = samples in - counted losses: exactly when no gap had to be estimated, else to
the precision of the fitted sensor clock (the MPU6050 has no sample counter, so a gap's length
comes from the clock fit; see tvsd.hw.imu_reader and SensorReader.lost)."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from tvsd.hw.imu_clock import ManualClock
from tvsd.hw.imu_reader import ImuReader, SensorReader
from tvsd.hw.mpu6050 import ImuSettings, Mpu6050
from tvsd.sim.mpu6050 import Fault, decode_counter, sil_pair

S = ImuSettings()
# power_cycle is left out: the part stops sampling while off, so there is no "sample in" to
# count; test_imu_reader covers its recovery.
KINDS = ["nack", "eio", "partial", "stall", "disconnect"]


@st.composite
def fault(draw: st.DrawFn) -> Fault:
    start = draw(st.floats(0.3, 2.5))
    return Fault(
        draw(st.sampled_from(KINDS)),
        start,
        start + draw(st.floats(0.0005, 0.4)),
        draw(st.sampled_from([None, 0x68, 0x69])),
    )


faults = st.lists(fault(), max_size=4)


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
@settings(max_examples=40, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow])
@given(schedule=faults, error_rate=st.sampled_from([0.0, 0.002, 0.02]), seed=st.integers(0, 99))
def test_samples_out_equal_samples_in_minus_counted_losses(schedule, error_rate, seed):
    clock = ManualClock()
    bus, devs = sil_pair(S, clock, signal="counter", seed=seed)
    bus.faults = schedule
    bus.error_rate = error_rate
    readers = [SensorReader(Mpu6050(bus, n, S, clock.sleep), clock) for n in ("pl", "sa")]
    batches = ImuReader(readers, clock).run_for(4.0)  # faults end by 2.9 s; back-off <= 0.5 s
    for r in readers:
        mine = [b for b in batches if b.sensor == r.name]
        raw = np.concatenate([b.raw for b in mine])
        k = np.concatenate([b.k for b in mine])
        n, ok = decode_counter(raw)
        assert ok.all(), "misaligned frame delivered"
        assert np.all(np.diff(n) > 0) and np.all(np.diff(k) > 0)
        n_in, out = int(n[-1] - n[0] + 1), len(n)
        assert out == r.samples
        if r.resyncs == 0:  # no gap needed estimating: exact
            assert n_in - out == r.lost == 0
        else:
            # Gaps are measured on the fitted sensor clock: the total is the phase of the last
            # epoch against the first, in whole periods (+-1 rounding), and a rate error dr
            # misplaces it by dr*T over the span T. A clean bus fits the rate to ~0.01 Hz;
            # resyncs every ~0.1 s (2 % errors) leave epochs of a few reads: ~0.5 Hz. The fit
            # reports its standard error; the truth must lie within 4 of them.
            rate_err = abs(r.fit.rate() - devs[r.name].rate_hz)
            assert rate_err < 4 * max(r.fit.rate_stderr, 0.005), (rate_err, r.fit.rate_stderr)
            span = (n[-1] - n[0]) / devs[r.name].rate_hz
            bound = 1 + int(np.ceil(rate_err * span))
            assert abs(n_in - out - r.lost) <= bound, (n_in, out, r.lost, r.resyncs, bound)
            if error_rate == 0:  # only bursts: few, long epochs, a rate good to ~0.01 Hz
                assert abs(n_in - out - r.lost) <= 1
        # and it came back, with samples from the last 0.3 s; with random errors still going
        # on, two failed polls in a row (p ~ 5 % at 2 %) may leave it degraded at the end
        assert max(b.t[-1] for b in mine) > 3.7
        if error_rate == 0:
            assert r.state == "ok", r.last_error
