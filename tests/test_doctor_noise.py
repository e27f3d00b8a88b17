"""The noise-colour test of tvsd.analysis.noise on the doctor's own processing (fast, synthetic).

A vibration acceleration (white, or Ornstein–Uhlenbeck with correlation time τ) is integrated to a
speed, measured with white noise at 1 kHz, and put through tvsd.analysis.prep as the doctor does;
the residual is then the band-limited acceleration rows themselves (no drive in the model).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter

from tvsd.analysis.dataset import ROTARY, Dataset
from tvsd.analysis.noise import analyse, processing_response
from tvsd.analysis.prep import Band, prepare

FS = 1000.0
SECONDS = 60.0
SPEED_NOISE = 0.02  # rad/s, the SIL's measurement noise


def _rows(seed: int, tau: float | None, intensity: float) -> tuple[np.ndarray, float, object]:
    """Acceleration rows of a vibration whose low-frequency one-sided PSD is 2·intensity²."""
    g = np.random.default_rng(seed)
    n = int(SECONDS * FS)
    dt = 1.0 / FS
    if tau is None:
        acc = intensity * g.standard_normal(n) / math.sqrt(dt)
    else:  # OU with the same low-frequency intensity: stationary std intensity/√(2τ)
        d = math.exp(-dt / tau)
        drive = intensity / math.sqrt(2 * tau) * math.sqrt(1 - d * d) * g.standard_normal(n)
        acc = lfilter([1.0], [1.0, -d], drive)
    speed = np.cumsum(acc) * dt + SPEED_NOISE * g.standard_normal(n)
    t = np.arange(n) * dt
    data = Dataset("synthetic", t, np.zeros(n), np.cumsum(speed) * dt, speed, FS, 1.0, 0.0, ROTARY, False)
    prep = prepare(data, Band())
    rate = 1.0 / float(np.median(np.diff(prep.t_rows)))
    return prep.rows(prep.accel), rate, prep


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_white_vibration_is_not_called_coloured(seed):
    """Under the white null the likelihood ratio is χ²₁: p < 1e-3 happens once in 1000 draws.
    The band filter's roll-off up to 90 Hz would look like a low-pass colour if the processing's
    response were not in the model (it is, through processing_response)."""
    rows, rate, prep = _rows(seed, None, 0.34)
    rep = analyse(rows, rate, 1.0, prep.band.cutoff_hz, processing_response(prep))  # type: ignore[attr-defined]
    assert rep.colour_p > 1e-3, rep.colour_p
    assert rep.sigma_v == pytest.approx(0.34, rel=0.1)  # 60 s of Welch segments: a few % spread


def test_a_5ms_correlation_is_seen_with_its_time():
    """τ = 5 ms puts the corner at 32 Hz, inside the band the response lets the test use (≤ 90 Hz);
    at σv = 0.34 and 60 s the ratio is far beyond χ²₁(1e-3) = 10.8, and τ comes out within a
    factor 1.5 (its spread over seeds is ≈ 10 %)."""
    rows, rate, prep = _rows(4, 0.005, 0.34)
    rep = analyse(rows, rate, 1.0, prep.band.cutoff_hz, processing_response(prep))  # type: ignore[attr-defined]
    assert rep.colour_p < 1e-3, rep.colour_p
    assert 0.005 / 1.5 < rep.tau_s < 0.005 * 1.5, rep.tau_s
