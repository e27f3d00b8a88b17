"""The 10 kHz control runner: function, never timing (docs/architecture.md: these machines wake threads late).

Every assertion here holds however late the machine wakes the thread: tick counts, the law's
arithmetic on what was recorded, the plant's physics over real elapsed time, the overrun logic
driven by a busy-wait hook (the overrun is then certain, not a matter of luck).
"""

from __future__ import annotations

import math
import os
import time
import tracemalloc

import numpy as np
import pytest
from conftest import wait_for
from numba.core.runtime import _nrt_python as nrt_stats  # type: ignore[attr-defined]
from numba.core.runtime import rtsys

from tvsd.control import scanning
from tvsd.control.runner import EXTRAPOLATE_MAX_NS, Runner
from tvsd.control.setup import Setup
from tvsd.model import params as P
from tvsd.model import plant as K


def _law(eps: float, eps_dot: float, g: tuple[float, float, float, float], umax: float) -> float:
    """Eq. (18), corrected sign, in plain Python: the reference the kernel is checked against."""
    gp, gd, gr, g0 = g
    u = gp * math.tanh(eps) + gd * math.tanh(eps_dot) + gr * math.tanh(g0 * eps)
    return max(-umax, min(umax, u))


def test_runs_n_ticks_then_stops_on_request(setup: Setup) -> None:
    r = Runner(setup)
    r.start(max_ticks=500)
    r.join(30.0)
    assert r.ticks == 500
    assert not r.is_running
    r.start()
    wait_for(lambda: r.ticks, 10.0, "100 ticks", ok=lambda n: n > 100)
    r.stop(5.0)
    stopped_at = r.ticks
    time.sleep(0.05)
    assert r.ticks == stopped_at, "ticks after stop"
    assert not r.is_running
    assert r.command == 0.0, "a stopped loop must command nothing"


def test_histogram_counts_every_tick(setup: Setup) -> None:
    r = Runner(setup)
    r.scan(20.0)
    r.start(max_ticks=3000)
    r.join(30.0)
    assert int(r.lateness_histogram().sum()) == r.ticks == 3000
    s = r.stats()
    assert s.ticks == 3000 and s.max_us >= 0.0 and s.p50_us <= s.p99_us <= s.p999_us


def test_scanning_command_is_the_law_of_what_it_saw(setup: Setup) -> None:
    r = Runner(setup)
    r.scan(20.0)
    r.start(max_ticks=4000)
    r.join(30.0)
    rec = r.recent_ticks()
    assert len(rec) == 4000
    g = setup.gains.as_tuple()
    p = setup.plant
    for k in range(1, len(rec)):
        row, prev = rec[k], rec[k - 1]
        dt = row["dt"]
        # The references advance by the measured step, which is the recorded wake-to-wake time.
        assert dt == pytest.approx(row["t"] - prev["t"], abs=1e-9)
        assert row["phi_ref"] - prev["phi_ref"] == pytest.approx(row["omega_ref"] * dt, abs=1e-12)
        alpha = (row["omega_ref"] - prev["omega_ref"]) / dt
        u_ff = scanning.feedforward.py_func(
            row["omega_ref"],
            alpha,
            p[P.P_J],
            p[P.P_KV] + p[P.P_S2],
            p[P.P_KM],
            p[P.P_KB],
            p[P.P_R],
            p[P.P_KU],
            p[P.P_TC],
            p[P.P_TS],
            p[P.P_V0],
        )
        assert row["u_ff"] == pytest.approx(u_ff, rel=1e-9, abs=1e-12)
        lim = max(setup.u_max - abs(u_ff), 0.0)
        eps = row["phi_ref"] - row["phi"]
        expect = _law(eps, row["omega_ref"] - row["omega"], g, lim) + u_ff
        assert row["u"] == pytest.approx(expect, abs=1e-12), f"tick {k}"


def test_hardware_mode_uses_the_measured_inputs(setup: Setup) -> None:
    """Without SIL the kernel reads φ, ω from the shared array the I/O side writes."""
    r = Runner(setup, sil=False)
    r.measured(0.1, 2.0)
    r.position(0.3)
    r.start()
    wait_for(lambda: r.ticks, 10.0, "50 ticks", ok=lambda n: n > 50)
    u_seen = r.command
    r.stop(5.0)
    expect = _law(0.3 - 0.1, -2.0, setup.gains.as_tuple(), setup.u_max)
    assert u_seen == pytest.approx(expect, abs=1e-12)
    rec = r.recent_ticks(10)
    assert np.all(rec["phi"] == 0.1) and np.all(rec["omega"] == 2.0)


def test_a_measurement_with_its_sampling_time_is_carried_forward_at_its_speed(setup: Setup) -> None:
    """With the MCU's sampling instant, each tick's φ is φ_s + ω·(wake − t_s): exactly, since the
    recorded t is the wake time on the same clock (capped at EXTRAPOLATE_MAX_NS)."""
    r = Runner(setup, sil=False)
    r.position(0.0)
    r.start()
    wait_for(lambda: r.ticks, 10.0, "5 ticks", ok=lambda n: n > 5)
    sample_ns = time.monotonic_ns()
    r.measured(0.1, 2.0, sample_ns=sample_ns)
    first = r.ticks
    wait_for(lambda: r.ticks, 10.0, "50 more ticks", ok=lambda n: n > first + 50)
    r.stop(5.0)
    rec = r.recent_ticks(40)
    start_ns = r.start_ns
    age = np.clip(start_ns + rec["t"] * 1e9 - sample_ns, 0, EXTRAPOLATE_MAX_NS) / 1e9
    # t is stored in float seconds since the start: ~1e-16 relative, ns exact to ~1e-6 s·ω
    np.testing.assert_allclose(rec["phi"], 0.1 + 2.0 * age, rtol=0, atol=1e-9)
    assert np.all(rec["omega"] == 2.0) and np.all(age > 0)


def test_sil_plant_spins_up_in_real_time(setup: Setup) -> None:
    """20 rev/s: the reference ramps at 10 rev/s² (2 s), the plant settles within ~0.5 s more.

    The plant advances by real elapsed time whatever the wake-up lateness, so only the bound on
    wall time is generous (8 s): late ticks worsen tracking, they do not slow the physics.
    """
    r = Runner(setup)
    r.scan(20.0)
    t0 = time.monotonic()
    r.start()
    try:
        wait_for(
            lambda: r.omega / (2 * math.pi),
            8.0,
            "the SIL plant at 20 rev/s ± 2 % after 2 s",
            ok=lambda rps: abs(rps - 20.0) < 0.02 * 20.0 and time.monotonic() - t0 > 2.0,
        )
    finally:
        wall = time.monotonic() - t0
        r.stop(5.0)
    sim_time = r.recent_ticks(1)["t"][0]
    assert wall >= 1.9, "the ramp cannot finish before 2 s of real time: the plant ran faster than real time"
    assert sim_time == pytest.approx(wall, abs=0.3)
    assert r.state[K.S_OMEGA] == r.omega


def test_overrun_streak_latches_the_safe_state(setup: Setup) -> None:
    """A busy wait of 3 periods per tick makes every tick wake ≥ 2 periods late: certain overrun."""
    r = Runner(setup, streak_limit=20)
    r.scan(20.0)
    r.inject_overrun(periods=3.0)
    r.start()
    wait_for(lambda: r.fault, 10.0, "the fault after sustained overrun")
    assert r.stats().late_ticks >= 20
    wait_for(lambda: r.command, 1.0, "command 0", ok=lambda u: u == 0.0)
    time.sleep(0.02)
    assert r.command == 0.0 and r.fault, "the safe state must latch"
    r.inject_overrun(0)
    r.stop(5.0)
    assert r.stats().missed_ticks >= 2 * r.stats().late_ticks - 1  # each late tick skipped ≥ 2
    # Every tick after the first is late, so the longest run is the whole run of late ticks.
    assert r.stats().longest_late_run >= 20
    assert r.stats().longest_late_run >= r.stats().late_ticks - 1


def test_unmeetable_period_trips_the_fault(setup: Setup) -> None:
    """A 2 µs period cannot be met (one clock_nanosleep costs more): the streak trips."""
    r = Runner(setup, period_s=2e-6, streak_limit=50)
    r.scan(20.0)
    r.start()
    wait_for(lambda: r.fault, 10.0, "the fault")
    r.stop(5.0)
    r.clear_fault()
    assert not r.fault


def test_no_allocation_per_tick(setup: Setup) -> None:
    """Python side: tracemalloc flat over 5000 ticks. Kernel: no NRT allocation per tick, in
    hardware mode and in SIL (the plant's delay ring lives in its state array)."""
    per_tick: dict[bool, float] = {}
    nrt_stats.memsys_enable_stats()  # NUMBA_NRT_STATS=1, switched on at run time
    for sil in (False, True):
        r = Runner(setup, sil=sil)
        r.measured(0.0, 0.0)
        r.position(0.2)
        counts = []
        for n in (200, 5200):
            a = rtsys.get_allocation_stats().alloc
            r.start(max_ticks=n)
            if n > 200:
                tracemalloc.start()
                before = tracemalloc.get_traced_memory()[0]
            r.join(30.0)
            if n > 200:
                grown = tracemalloc.get_traced_memory()[0] - before
                tracemalloc.stop()
                assert grown < 16_000, f"Python side grew {grown} B over 5000 ticks"
            counts.append(rtsys.get_allocation_stats().alloc - a)
        per_tick[sil] = (counts[1] - counts[0]) / 5000
    nrt_stats.memsys_disable_stats()
    assert per_tick[False] == 0.0
    assert per_tick[True] == 0.0


def test_no_allocation_per_tick_with_the_kernels_heartbeat(setup: Setup) -> None:
    """The kernel writing a heartbeat every tick (and PWM 0 behind it: its stale fault latched),
    to /dev/null through the shared port: still no NRT allocation per tick, and every write
    whole (errors 0)."""
    fd = os.open(os.devnull, os.O_WRONLY)
    nrt_stats.memsys_enable_stats()
    try:
        r = Runner(setup, sil=False)
        r.tx.open(fd)
        r.attach_link(1e-4, 0xA5, 0x02, 0x03)  # due every tick
        r.stale_after(1e-3)
        r.measured(0.0, 0.0, t_ns=1)  # long stale: the fault latches on the first tick
        r.position(0.2)
        counts = []
        for n in (200, 5200):
            a = rtsys.get_allocation_stats().alloc
            r.start(max_ticks=n)
            r.join(30.0)
            counts.append(rtsys.get_allocation_stats().alloc - a)
        hb = r.heartbeat_stats()
    finally:
        nrt_stats.memsys_disable_stats()
        r.tx.close()
        os.close(fd)
    assert r.fault and hb.sent > 1000 and hb.cuts > 1000 and hb.errors == 0, hb
    assert (counts[1] - counts[0]) / 5000 == 0.0


def test_late_input_within_the_stale_limit_is_carried_forward_to_it(setup: Setup) -> None:
    """A measurement 30 ms old, with the stale limit at 200 ms, is input the law acts on: its
    angle is carried forward over its whole age, not held after EXTRAPOLATE_MAX_NS (10 ms). Held,
    the angle reference ran on against a frozen angle, slipped at +max_lag, and the late frames'
    true angle then left the shaft max_lag ahead: the spin scan's sag to 18.9 rev/s. Exact as
    the test above (the recorded t is the wake time on the same clock)."""
    r = Runner(setup, sil=False)
    r.position(0.0)
    r.start()
    wait_for(lambda: r.ticks, 10.0, "5 ticks", ok=lambda n: n > 5)
    sample_ns = time.monotonic_ns() - 30_000_000
    r.measured(0.1, 2.0, sample_ns=sample_ns)
    r.stale_after(0.2, 0.5)  # after the first measurement: none yet would latch STALE at once
    first = r.ticks
    wait_for(lambda: r.ticks, 10.0, "50 more ticks", ok=lambda n: n > first + 50)
    r.stop(5.0)
    assert not r.held and not r.fault
    rec = r.recent_ticks(40)
    age = (r.start_ns + rec["t"] * 1e9 - sample_ns) / 1e9
    assert np.all(age > EXTRAPOLATE_MAX_NS / 1e9) and np.all(age < 0.2)
    np.testing.assert_allclose(rec["phi"], 0.1 + 2.0 * age, rtol=0, atol=1e-9)
