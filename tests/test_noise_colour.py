"""The noise-colour test's null calibration (tvsd.analysis.noise): its likelihood ratio is read as
χ² with one degree of freedom, so on white residuals it must not reject more often than that."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binom, chi2

from tvsd.analysis.noise import colour_test, effective_segments


def test_effective_segments_of_the_hann_welch_spectrum() -> None:
    """One Hann segment is worth 18/35 of itself (its power bins correlate 4/9 and 1/36 at one
    and two bins: 1 + 2·(4/9 + 1/36) = 35/18); many 50 %-overlapped ones 9/19 of their count
    (the squared samples' weights Σ w² over the segments: mean W² = 19/32 against (3/8)²·2)."""
    assert effective_segments(1, 1000) == pytest.approx(18 / 35, rel=1e-3)
    assert effective_segments(2000, 1000) / 2000 == pytest.approx(9 / 19, rel=2e-3)
    assert effective_segments(14, 1000) == pytest.approx(14 / 2.0992, rel=1e-3)  # the doctor's 30 s


def _white_residual(seed: int, n: int = 7500) -> np.ndarray:
    """The doctor's residual rows without colour: flat vibration + differentiated measurement
    noise, 30 s at 250 Hz."""
    g = np.random.default_rng(seed)
    return g.standard_normal(n) + 0.3 * np.diff(g.standard_normal(n + 1))


@pytest.mark.slow
def test_white_residuals_reject_no_more_often_than_the_nominal_level() -> None:
    """400 white residuals. The ratio's null is the boundary mixture ½χ²₀ + ½χ²₁ (τ = 0 is the
    white shape): mean ½, variance 5/4, so the mean of 400 stays below ½ + 3.1·√(5/4/400) = 0.67
    (99.9 %); and the count of p < α (p read from χ²₁) within the binomial(400, α) 99.9 % point
    (35 at α = 5 %, 11 at α = 1 %). The ratio summed over the Welch spectrum's 14 segments as if
    they were independent (the old statistic, 2.1× this one) fails: mean 0.96, 16 at α = 1 %."""
    lr = np.array([colour_test(_white_residual(1000 + s), 250.0, 100.0)[0] for s in range(400)])
    assert lr.mean() < 0.5 + 3.1 * math.sqrt(1.25 / len(lr))
    p = chi2.sf(lr, 1)
    for alpha in (0.05, 0.01):
        assert np.count_nonzero(p < alpha) <= binom.ppf(0.999, len(p), alpha), alpha
