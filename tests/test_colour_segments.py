"""The colour test's likelihood ratio on residuals whose rows differ in level: the first 20–50 % left
out as zeros where the shaft was stuck (noise.rows_worth, docs/measurements/colourseg.md).

Nulls: the doctor's residual without colour (flat vibration + differentiated measurement noise, any
mix; 250 Hz rows, 30 s). Effects: the same plus an Ornstein–Uhlenbeck (low-pass) vibration,
τ 10–50 ms, of rms 0.3 of the flat part's (1): 20 of 20 are named on the whole record, and
10–13 of 20 at 0.2, so 0.3 is the size the test is sure of, not a far-off one."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import lfilter
from scipy.stats import chi2

from tvsd.analysis import noise
from tvsd.analysis.matrix import clopper_pearson

RATE, N = 250.0, 7500


def _white(rng: np.random.Generator) -> np.ndarray:
    mix = rng.uniform(0.0, 1.0)
    return (
        math.sqrt(1.0 - mix) * rng.standard_normal(N)
        + math.sqrt(mix) * np.diff(rng.standard_normal(N + 1)) / 2
    )


def _stuck(rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
    y = x.copy()
    y[: int(rng.uniform(0.2, 0.5) * len(x))] = 0.0
    return y


def test_rows_worth_is_the_segment_count_on_one_level_and_less_on_zeros() -> None:
    """On one level it is effective_segments of the count, to within the local power's sampling
    scatter (2/(nper/4) = 0.8 % low at nper 1000: the count's mean over 20 draws within 2 % of
    it); with the first 40 % left out it is close to that of the 8 segments left whole (3.83),
    and above it by the part of the onset's segments that holds rows."""
    rng = np.random.default_rng(5)
    whole = [noise.rows_worth(rng.standard_normal(N), 1000) for _ in range(20)]
    assert float(np.mean(whole)) == pytest.approx(noise.effective_segments(14, 1000), rel=0.02)
    x = rng.standard_normal(N)
    x[:3000] = 0.0
    assert noise.effective_segments(8, 1000) < noise.rows_worth(x, 1000) < noise.effective_segments(9, 1000)


@pytest.mark.slow
def test_a_stuck_start_does_not_make_white_residuals_coloured() -> None:
    """400 white residuals with their first 20–50 % left out. The ratio's null is ½χ²₀ + ½χ²₁
    (mean ½, variance 5/4): the mean of 400 stays below ½ + 3.1·√(5/4/400) = 0.67 (99.9 %), and
    the false-alarm rate at the doctor's gate (p < COLOUR_P) must have COLOUR_P inside its 95 %
    Clopper–Pearson interval's reach (lower end ≤ COLOUR_P). Counted on every segment (integ3)
    the same draws read mean 0.83 and 4/400 at the gate (0.27–2.5 %); on the rows' worth 0.55
    and 1/400."""
    rng = np.random.default_rng(20261130)
    lr = np.array([noise.colour_test(_stuck(rng, _white(rng)), RATE, 100.0)[0] for _ in range(400)])
    assert lr.mean() < 0.5 + 3.1 * math.sqrt(1.25 / len(lr)), lr.mean()
    alarms = int(np.count_nonzero(chi2.sf(lr, 1) < noise.COLOUR_P))
    low, _ = clopper_pearson(alarms, len(lr))
    assert low <= noise.COLOUR_P, (alarms, low)


def test_a_coloured_residual_with_a_stuck_start_is_still_named() -> None:
    """An OU vibration (τ 10–50 ms) of rms 0.3 of the flat part's, in the same gapped family:
    all 20 named at the doctor's gate."""
    rng = np.random.default_rng(20261131)
    named = 0
    for _ in range(20):
        x = _white(rng)
        r = math.exp(-1.0 / (RATE * rng.uniform(0.01, 0.05)))
        ou = lfilter([1.0], [1.0, -r], rng.standard_normal(N))
        y = _stuck(rng, x + 0.3 * ou / ou.std())
        named += noise.colour_test(y, RATE, 100.0)[1] < noise.COLOUR_P
    assert named == 20, named
