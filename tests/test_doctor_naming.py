"""What the per-cause naming figures rest on (README, "What it cannot name"): the matrix's
open-loop effect sizes put the effect in the data, thresholds need commands strictly on both
sides, and the residual spectrum's peak is told from a low-pass colour before the colour test."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.signal import lfilter

from tvsd.analysis import matrix
from tvsd.analysis.design import SUPPORT, supported_threshold
from tvsd.analysis.noise import analyse, spectral_cause
from tvsd.analysis.peak import PEAK_Q
from tvsd.config import load_config


@pytest.mark.parametrize("profile", ["steps", "multisine"])
def test_open_loop_saturation_sizes_clip_the_recorded_command(profile: str) -> None:
    """At every matrix size at least 1 % of the command exceeds u_max (the threshold is below the
    command's 99 % quantile), and a larger size clips more: the effect is in the data."""
    cfg = load_config()
    u = matrix.open_loop_command(cfg, profile, 30.0, 60_007)
    shares, excesses = [], []
    for m in matrix.SIZES:
        u_max, excess = matrix.saturation_size(u, m)
        shares.append(float(np.mean(np.abs(u) > u_max)))
        excesses.append(excess)
    assert min(shares) >= 0.01
    assert all(b > a for a, b in itertools.pairwise(excesses))


def test_the_recorded_command_is_the_one_the_matrix_sized() -> None:
    """`sim record` plays the command open_loop_command predicts (same rng, same shape)."""
    cfg = load_config()
    case = next(c for c in matrix.cases(n_null=0, reps=1, seed=6, causes=("saturation",)) if c.size == 1.0)
    u = matrix.open_loop_command(cfg, case.profile, 30.0, case.seed)
    u_max = float(case.effect.split("=")[1])  # type: ignore[union-attr]
    assert float(np.mean(np.abs(u) > u_max)) >= 0.01


def test_coloured_cases_keep_the_nulls_low_frequency_intensity() -> None:
    """The OU's two-sided PSD at 0, 2σ²τ, equals the white vibration's σv² for every size."""
    for case in matrix.cases(n_null=0, reps=3, seed=6, causes=("colored_noise",)):
        tau = float(case.effect.split("=")[1])  # type: ignore[union-attr]
        white = matrix.SIGMAS[
            [round(case.sigma_v * math.sqrt(2 * tau) / s, 9) for s in matrix.SIGMAS].index(1.0)
        ]
        assert 2 * case.sigma_v**2 * tau == pytest.approx(white**2, rel=1e-12)


class _Prep:
    def __init__(self, u: np.ndarray) -> None:
        self.data = type("D", (), {"u": u})()


def test_a_threshold_at_the_top_level_of_a_staircase_is_not_supported() -> None:
    """A staircase holds its top level exactly: a saturation there clips nothing, so it is no
    candidate, though ≥ 1 % of the samples are 'not below' it; just under it, it is."""
    u = np.repeat([1.0, -3.0, 5.0, -8.0, 10.0], 200)
    assert not supported_threshold(_Prep(u), 10.0)  # type: ignore[arg-type]
    assert supported_threshold(_Prep(u), 9.9)  # type: ignore[arg-type]
    assert not supported_threshold(_Prep(u), 0.999)  # type: ignore[arg-type]  # nothing below
    assert SUPPORT == 0.01


def _residual(kind: str, seed: int, n: int = 7500, fs: float = 250.0) -> np.ndarray:
    """A residual like the doctor's rows: flat vibration + differentiated measurement noise, and
    a noise-driven mode (Q ≈ 12 at 30 Hz) or a low-pass (OU, 20 ms) vibration."""
    g = np.random.default_rng(seed)
    w = g.standard_normal(n + 1)
    meas = 0.3 * np.diff(w)
    if kind == "mode":
        f0, q = 30.0, 12.0
        r = math.exp(-math.pi * f0 / (q * fs))
        mode = lfilter([1.0], [1.0, -2 * r * math.cos(2 * math.pi * f0 / fs), r * r], g.standard_normal(n))
        return g.standard_normal(n) + 0.25 * mode + meas
    if kind == "lowpass":
        a = math.exp(-1.0 / (0.02 * fs))
        return 6.0 * lfilter([1.0 - a], [1.0, -a], g.standard_normal(n)) + 0.3 * g.standard_normal(n) + meas
    return g.standard_normal(n) + meas


def test_the_spectrum_names_a_mode_a_low_pass_and_nothing() -> None:
    """A noise-driven mode is a resonance (peak first, Q ≥ PEAK_Q); a low-pass vibration is
    coloured noise; a flat one with measurement noise is nothing. Thresholds: PEAK_WHITE_LR is
    the 99.9 % point of 500 simulated nulls (noise.py), the colour test p < 1e-3."""
    mode = analyse(_residual("mode", 1), 250.0, 1.0, 100.0)
    assert spectral_cause(mode, 1e-3) == "resonance"
    assert mode.peak_hz == pytest.approx(30.0, abs=1.0) and mode.peak_q >= PEAK_Q
    assert spectral_cause(analyse(_residual("lowpass", 2), 250.0, 1.0, 100.0), 1e-3) == "colored_noise"
    assert spectral_cause(analyse(_residual("flat", 3), 250.0, 1.0, 100.0), 1e-3) is None


def test_open_loop_delays_have_noise_units_from_their_command() -> None:
    """A delay's size in noise units is b_u·rms(u(t) − u(t − τ))/(J·σv), from the known command:
    larger for a longer delay of the same case draw (same plant, command and σv)."""
    cfg = load_config()
    case = matrix.cases(n_null=0, reps=1, seed=6, causes=("delay",))[0]
    u = matrix.open_loop_command(cfg, case.profile, 30.0, case.seed)
    b_u = case.plant["kM"] * cfg.plant.ku / case.plant["R"]
    dt = 1.0 / cfg.control.rate_hz
    expected = matrix.delay_torque(u, 0.0005, b_u, dt) / (case.plant["J"] * case.sigma_v)
    assert case.noise_units == pytest.approx(expected, rel=1e-9)
    assert matrix.delay_torque(u, 0.0015, b_u, dt) > matrix.delay_torque(u, 0.0005, b_u, dt) > 0
