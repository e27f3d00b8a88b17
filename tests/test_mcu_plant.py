"""The SIL bridge: drive model ⇄ the real firmware core (virtual MCU) ⇄ McuLink over a real pty.

The host sets the PWM through McuLink; the firmware's duty drives the model; the model's shaft
feeds the firmware's encoder and pulse inputs; the firmware's frames come back over the pty.
The plant runs paced at SPEED × real time on the MCU's manual clock.
"""

from __future__ import annotations

import asyncio
import itertools
import math
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from conftest import until

from tvsd.config import Config, VibrationConfig, load_config
from tvsd.hw.mcu.events import PulseEvent
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.placement import StateSample
from tvsd.hw.mcu.settings import McuSettings
from tvsd.model.plant import S_OMEGA
from tvsd.scan.geometry import doe_b_target, inverse
from tvsd.sim import mcu_plant as mp
from tvsd.sim import virtual_mcu as vm

SPEED = 5.0  # sim seconds per wall second: heartbeats every 20 ms wall are 100 ms of MCU time
DUTY = 0.5
HZ = 16_000_000
TICK = 1.0 / HZ
OFF = VibrationConfig(model="off")


@contextmanager
def bridge(
    cfg: Config,
    target: mp.Target | None = None,
    vibration: VibrationConfig | None = None,
    initial_state: np.ndarray | None = None,
) -> Iterator[mp.McuPlant]:
    try:
        plant = mp.McuPlant(
            cfg, target or mp.Target(), speed=SPEED, vibration=vibration, initial_state=initial_state
        )
    except vm.VirtualMcuError as exc:
        pytest.skip(f"virtual MCU unavailable: {exc}")
    with plant:
        yield plant


wait = until  # the shared poll


async def spin(
    plant: mp.McuPlant,
    sim_s: float,
    states: list[StateSample],
    pulses: list[PulseEvent],
    clock_ready: bool = False,
) -> McuLink:
    """Open the link, set the duty, run the plant to sim_s (and, if asked, until the clock sync
    has its samples) and wait for the last frame. Timeouts allow a loaded host to run the plant
    at a fraction of SPEED."""
    # link_timeout 10 s: a stall of this process (it paces the plant) must not read as a link loss,
    # which would break the chain of stamps that `exact` and the 1 ms steps below check
    settings = McuSettings(port=plant.mcu.port, link_lost_ms=10_000)
    link = McuLink(settings, on_state=states.append, on_pulse=pulses.append)
    async with link:
        # 2 s of MCU time: a heartbeat late on a loaded host must not trip the watchdog
        assert link.send_config(watchdog_ms=2000, state_div=10, max_on_ms=0)
        assert link.send_pwm(DUTY)
        await wait(lambda: plant.mcu.pwm_duty == round(DUTY * 32767) / 32767, 2.0, "duty applied")
        plant.start()
        await wait(lambda: plant.t >= 0.05, 5.0, "the plant runs")
        link.restart_clock_sync()  # its first round trips saw the manual clock held at 0

        def done() -> bool:
            ready = link.clock is not None and link.clock.ready
            return plant.t >= sim_s and (ready or not clock_ready)

        await wait(done, 20.0 + 5 * sim_s / SPEED, f"{sim_s} s of plant (clock sync ready: {clock_ready})")
        await link.stop_heartbeat()  # no round trip may see the clock held once the plant stops
        plant.stop()
        last = round(plant.t * HZ) - 16_000  # the state frame of the last millisecond
        await wait(lambda: bool(states) and states[-1].mcu_ticks >= last, 5.0, "the last state frame")
    return link


def test_pwm_spins_the_plant_and_the_firmware_reads_it() -> None:
    cfg = load_config()
    states: list[StateSample] = []
    pulses: list[PulseEvent] = []
    with bridge(cfg) as plant:
        link = asyncio.run(spin(plant, 2.0, states, pulses))
        st = link.stats()
        assert st.lost_frames == st.crc_errors == st.lost_events == st.states_unanchored == 0
        # the firmware's duty reached the model: spun up from rest (≈ 2 rev/s after 2 s at 6 V)
        assert plant.mcu.motor_volts == pytest.approx(DUTY * cfg.drive.u_max_v, abs=1e-3)
        assert plant.omega / math.tau > 1.5
        # every state frame is placed exactly (the link anchors the pre-heartbeat ones too),
        # 1 ms apart, and reads the plant's angle: the count held at the frame's stamp
        assert all(s.exact for s in states)
        assert {b.mcu_ticks - a.mcu_ticks for a, b in itertools.pairwise(states)} == {16_000}
        cpr = plant.counts_per_rev
        worst = max(abs(s.encoder - plant.angle_at(s.mcu_ticks * TICK) / math.tau * cpr) for s in states)
        assert worst <= 1.0, f"encoder off the plant's angle by {worst:.2f} counts"
        assert states[-1].encoder > 3 * cpr  # several revolutions, past the i16 wrap
        # one zero pulse per revolution, none lost, stamped at the crossing of 2πk to a tick
        zero = [p for p in pulses if p.channel == vm.PULSE_ZERO]
        revs = math.floor(plant.angle / math.tau)
        assert len(zero) == revs >= 3
        assert [b.event_seq - a.event_seq for a, b in itertools.pairwise(pulses)] == [1] * (len(pulses) - 1)
        t_log, a_log = np.array(plant.shaft_t), np.array(plant.shaft_angle)
        truth = np.interp(math.tau * np.arange(1, revs + 1), a_log, t_log)  # angle increases
        assert np.abs(np.array([p.mcu_ticks for p in zero]) * TICK - truth).max() <= TICK


def test_beta_from_the_pulse_stamps_matches_the_target() -> None:
    """β from the firmware's stamps, through ClockSync, against the target's β (geometry).

    Tolerance: the plant starts at its steady state for the set duty, with vibration off, so the
    speed is constant (|α| < 1e-8 rad/s²) and the chunk's linear interpolation is exact; each stamp
    is then the crossing time rounded to the 16 MHz timer, |δ| ≤ q/2 (q = 62.5 ns). With
    β̂ = 2π·(t_o − t_z)/(t_z' − t_z) = 2π·(t_o − t_z)/T:
        |β̂ − β| ≤ (2π·(|δ_o| + |δ_z|) + β·(|δ_z'| + |δ_z|)) / T ≤ (2π + β)·q / T
    ≈ 1.5e-5 rad at 25 rev/s (T = 39 ms). Sync: the three stamps go through one ClockSync fit,
    host = a + b·ticks; a and b cancel in the ratio, leaving the float rounding of host times
    (≤ 3 ulp ≈ 1e-9 s of the monotonic clock here, counted as 2 × 1e-9 s more in each difference).
    """
    cfg = load_config()
    volts = round(DUTY * 32767) / 32767 * cfg.drive.u_max_v
    state = mp.steady_state(cfg, volts, vibration=OFF)
    target = mp.Target(phi_deg=30.0, gamma_deg=5.0, range_m=2.0)
    states: list[StateSample] = []
    pulses: list[PulseEvent] = []
    with bridge(cfg, target=target, vibration=OFF, initial_state=state) as plant:
        # β is the inverse of eqs. (1)–(3) for the target (before the stepper quantises φ, γ)
        xyz = doe_b_target(target.phi_deg, target.gamma_deg, target.range_m, cfg.geometry.baseline_m)
        assert plant.beta == pytest.approx(float(inverse(*xyz, cfg.geometry.baseline_m)[1]), abs=2e-3)
        link = asyncio.run(spin(plant, 1.0, states, pulses, clock_ready=True))
        assert link.stats().lost_events == 0 and link.clock is not None and link.clock.ready
        clock = link.clock
        zero = [clock.to_host(p.mcu_ticks) for p in pulses if p.channel == vm.PULSE_ZERO]
        opt = [clock.to_host(p.mcu_ticks) for p in pulses if p.channel == vm.PULSE_OPTICAL]
        assert len(opt) == len(plant.optical_times) >= 20
        assert clock.fit_ is not None
        q_host = clock.fit_.seconds_per_tick  # one tick in host seconds
        checked, worst, worst_tol = 0, 0.0, 0.0
        for t_o in opt:
            k = int(np.searchsorted(zero, t_o)) - 1
            if k < 0 or k + 1 >= len(zero):
                continue
            period = zero[k + 1] - zero[k]
            beta = math.tau * (t_o - zero[k]) / period
            tol = ((math.tau + plant.beta) * q_host + 4e-9 * (math.tau + plant.beta)) / period
            assert abs(beta - plant.beta) <= tol, f"β off by {beta - plant.beta:.3g} rad (tol {tol:.3g})"
            checked += 1
            worst, worst_tol = max(worst, abs(beta - plant.beta)), max(worst_tol, tol)
        assert checked >= 20
        print(
            f"β = {plant.beta:.6f} rad: {checked} revolutions, "
            f"|error| ≤ {worst:.2e} rad (tolerance {worst_tol:.2e})"
        )
        # and ClockSync maps the manual clock onto the wall clock it was paced on: within its own
        # worst-case bound (half the slowest round trip it kept, through the line fit's weights:
        # ms beside a loaded host, whose pty hands the heartbeats over late), plus however far the
        # core fell behind the pacing line
        p = plant.pacing
        tol = clock.error_bound_s(round(plant.t * HZ)) + p.lag_max_s / SPEED
        assert clock.to_host(round(plant.t * HZ)) == pytest.approx(p.truth_host(plant.t, SPEED), abs=tol)


def test_a_fast_winding_is_integrated_stably() -> None:
    """plant.L = 0.1 mH passes the config's checks; at one RK4 step per 10 kHz tick its
    electrical pole has h·R/L ≈ 11, past RK4's 2.8, and the SIL plant diverged (the SIL process
    never answered its start). With the offline simulator's substeps the steady speed at a
    constant voltage is the paper motor's: L sets only the electrical time constant (≤ 1 ms
    here), so after 2 s the two agree to the integration's accuracy, not to a physical margin."""
    import dataclasses

    cfg = load_config()
    fast = dataclasses.replace(cfg, plant=dataclasses.replace(cfg.plant, L=1e-4))
    plant = mp.McuPlant(fast, mp.Target(), speed=SPEED, vibration=OFF)
    assert plant.setup.substeps > 1
    ref = mp.steady_state(cfg, 6.0, seconds=2.0, vibration=OFF)
    got = mp.steady_state(fast, 6.0, seconds=2.0, vibration=OFF)
    assert np.all(np.isfinite(got))
    assert got[S_OMEGA] == pytest.approx(ref[S_OMEGA], rel=1e-3)


def test_late_frames_share_the_chunk_in_their_order() -> None:
    """Frames that reached the plant after their chunk's start (the pty hands each millisecond's
    frames over at once: two per 1 ms chunk at the ATmega's 2 kHz) each hold an equal share of the
    next chunk, in order, so the volts the motor integrates are the frames' mean, not the last
    one's; a frame on time later in the chunk takes over from its step on."""
    cfg = load_config()
    with bridge(cfg, vibration=OFF) as plant:
        plant.mcu.pwm_changes = lambda: ([], 0.0)  # type: ignore[method-assign]  # no new frames
        volts, n, dt, t0 = plant.mcu.drive_volts, plant._n, plant.setup.dt, 1.0
        assert n == 10
        plant._pwm_pending = deque([(t0 - 0.4e-3, 0.25), (t0 - 0.4e-3, 0.75)])
        plant._chunk_volts(t0)
        assert plant._u.tolist() == [0.25 * volts] * 5 + [0.75 * volts] * 5
        plant._pwm_pending = deque([(t0 - 0.2e-3, 0.5), (t0 + 7 * dt, -0.5)])
        plant._chunk_volts(t0)
        assert plant._u.tolist() == [0.5 * volts] * 7 + [-0.5 * volts] * 3
