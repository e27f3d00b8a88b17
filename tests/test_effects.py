"""The effects library: each cause does to the plant what docs/architecture.md's vocabulary says."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from tvsd.causes import parse_effect, parse_effects
from tvsd.config import VibrationConfig, load_config
from tvsd.control.setup import Setup
from tvsd.errors import UsageError
from tvsd.model.lugre import steady_friction
from tvsd.sim import metrics, runs

OFF = VibrationConfig(model="off")


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def _setup(cfg, *texts: str, vib: VibrationConfig = OFF) -> Setup:
    return Setup.from_config(cfg, effects=parse_effects(texts), vibration=vib)


def _steady(trace: runs.Trace, seconds: float) -> np.ndarray:
    return trace.t >= trace.t[-1] - seconds


def test_imbalance_is_a_once_per_revolution_torque_with_its_phase(cfg):
    A, psi = 6e-5, 0.7
    trace = runs.spin(_setup(cfg, f"imbalance:amplitude={A},phase={psi}"), 20.0, 8.0)
    s = _steady(trace, 4.0)
    # Regress the disturbance on sin φ, cos φ: A·sin(φ+ψ)/J = (A/J)(cos ψ sin φ + sin ψ cos φ).
    X = np.column_stack([np.sin(trace.phi[s]), np.cos(trace.phi[s])])
    b, *_ = np.linalg.lstsq(X, trace.disturbance[s], rcond=None)
    # The torque is evaluated at the step's midpoint angle while φ is the end-of-step angle:
    # a phase lag of ω·dt/2 = 6.3 mrad at 20 rev/s, below the 0.01 rad tolerance.
    assert math.hypot(*b) == pytest.approx(A / cfg.plant.J, rel=1e-3)
    assert math.atan2(b[1], b[0]) == pytest.approx(psi, abs=0.01)
    hz, _ = metrics.dominant_frequency(trace.disturbance[s], 1.0 / (trace.t[1] - trace.t[0]))
    assert hz == pytest.approx(20.0, abs=0.1)


def test_cogging_line_sits_at_order_times_the_rotation_rate(cfg):
    trace = runs.spin(_setup(cfg, "cogging:order=6,amplitude=2e-5"), 5.0, 5.0)
    s = _steady(trace, 2.0)
    hz, _ = metrics.dominant_frequency(trace.disturbance[s], 10000.0, resolution_hz=0.5)
    assert hz == pytest.approx(30.0, abs=0.25)


@pytest.mark.parametrize("rps", [10.0, 20.0])
def test_resonance_line_is_fixed_in_hz_whatever_the_speed(cfg, rps):
    trace = runs.spin(_setup(cfg, "resonance:frequency_hz=47,amplitude=3e-5"), rps, 5.0)
    s = _steady(trace, 2.0)
    hz, amp = metrics.dominant_frequency(trace.disturbance[s], 10000.0, resolution_hz=0.5)
    assert hz == pytest.approx(47.0, abs=0.25)
    # Line amplitude from a Hann-windowed Welch estimate: within 10 % (scalloping off-bin ≤ 15 %,
    # here 47 Hz is on a 0.5 Hz bin, so the bound is loose on purpose but not vacuous).
    assert amp == pytest.approx(3e-5 / cfg.plant.J, rel=0.1)


def test_saturation_clips_the_applied_voltage(cfg):
    trace = runs.open_loop(_setup(cfg, "saturation:u_max=5"), np.array([10.0, -10.0, 3.0]))
    assert list(trace.u_applied) == [5.0, -5.0, 3.0]


def test_deadzone_outputs_nothing_inside_and_shifts_outside(cfg):
    trace = runs.open_loop(_setup(cfg, "deadzone:u0=1.0"), np.array([0.5, -0.9, 3.0, -3.0]))
    assert list(trace.u_applied) == [0.0, 0.0, 2.0, -2.0]


def test_delay_shifts_the_command_by_whole_and_fractional_steps(cfg):
    u = np.zeros(60)
    u[10:] = 4.0
    whole = runs.open_loop(_setup(cfg, "delay:delay_s=0.0025"), u)  # 25 steps of 0.1 ms
    assert np.nonzero(whole.u_applied)[0][0] == 35
    half = runs.open_loop(_setup(cfg, "delay:delay_s=0.00025"), u)  # 2.5 steps: interpolated
    assert half.u_applied[12] == pytest.approx(2.0) and half.u_applied[13] == pytest.approx(4.0)


def _balance_speed(p, u: float, level: float) -> float:
    def balance(w: float) -> float:
        return p.kM * (p.ku * u - p.kb * w) / p.R - level * (
            p.kv * w + steady_friction(w, p.tau_c, p.tau_s, p.v0, 0)
        )

    return brentq(balance, 1e-6, 1e4)


def test_friction_asymmetry_scales_friction_in_the_negative_direction(cfg):
    setup = _setup(cfg, "friction_asymmetry:ratio=2.0")
    pos = runs.open_loop(setup, np.full(300_000, 6.0), decim=1000).omega[-1]
    neg = runs.open_loop(setup, np.full(300_000, -6.0), decim=1000).omega[-1]
    assert pos == pytest.approx(_balance_speed(cfg.plant, 6.0, 1.0), rel=1e-4)
    assert -neg == pytest.approx(_balance_speed(cfg.plant, 6.0, 2.0), rel=1e-4)


def test_colored_noise_turns_the_white_sde_into_an_ou_process(cfg):
    vib = VibrationConfig(model="sde", sigma_v=0.5)
    trace = runs.open_loop(_setup(cfg, "colored_noise:tau_s=0.01", vib=vib), np.zeros(200_000))
    a = trace.disturbance
    lag = 100  # = tau / dt: correlation e^-1
    assert np.corrcoef(a[:-lag], a[lag:])[0, 1] == pytest.approx(math.exp(-1), abs=0.07)


def test_drift_moves_the_parameter_linearly_over_the_run(cfg):
    plant = cfg.plant
    seconds, rel = 60.0, 0.5
    trace = runs.open_loop(
        _setup(cfg, f"drift:parameter=kv,relative_change={rel}"),
        np.full(round(seconds * 1e4), 6.0),
        decim=1000,
    )
    end_plant = dataclasses.replace(plant, kv=plant.kv * (1 + rel))
    quasi_static = _balance_speed(end_plant, 6.0, 1.0)
    # The speed lags its quasi-static value by about τ_mech·|dω_ss/dt| (τ_mech = 2.4 s).
    slope = abs(quasi_static - _balance_speed(plant, 6.0, 1.0)) / seconds
    lag = trace.omega[-1] - quasi_static
    assert 0 < lag < 2 * 2.4 * slope


@pytest.mark.parametrize(
    "text,needle",
    [
        ("wobble:amplitude=1", "unknown effect 'wobble'"),
        ("imbalance:amplitud=1", "unknown parameter 'amplitud'"),
        ("cogging:amplitude=1e-4", "missing 'order'"),
        ("cogging:order=2.5,amplitude=1e-4", "whole number"),
        ("saturation:u_max=-3", "outside"),
        ("deadzone:u0=abc", "not a number"),
        ("drift:parameter=L,relative_change=0.1", "cannot drift"),
        ("delay:0.01", "not key=value"),
    ],
)
def test_bad_effects_say_what_was_wrong(text, needle):
    with pytest.raises(UsageError, match=needle):
        parse_effect(text)


def test_an_effect_given_twice_is_refused():
    with pytest.raises(UsageError, match="given twice"):
        parse_effects(["deadzone:u0=1", "deadzone:u0=2"])


def test_a_run_split_across_calls_equals_one_call(cfg):
    """A caller stepping the plant tick by tick (control thread, MCU bridge) keeps time-based
    effects and the delay ring continuous through the state array (tvsd.model.plant.state_array)."""
    from tvsd.model import plant as K

    setup = _setup(cfg, "resonance:frequency_hz=37,amplitude=3e-5", "delay:delay_s=0.0023")
    u = np.where(np.arange(400) >= 50, 5.0, 0.0)
    whole = K.state_array(setup.dt)
    one = runs.open_loop(setup, u, state=whole)
    split_state = K.state_array(setup.dt)
    parts = [runs.open_loop(setup, u[a : a + 100], state=split_state) for a in range(0, 400, 100)]
    joined = np.concatenate([p.omega for p in parts])
    assert np.array_equal(np.concatenate([p.u_applied for p in parts]), one.u_applied)
    assert np.allclose(joined, one.omega, rtol=0, atol=1e-12)
