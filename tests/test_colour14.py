"""The spectral tests' residual refitted in open loop (tvsd.analysis.spectral_fit): outsider nulls of
the two classes whose colour false alarms it removes, drawn fresh, not the files it was traced on
(o14033, o14073; docs/measurements/colour14.md).

- `coarse`: a V drive with an 8-bit PWM on a staircase, ω the difference of a 256-count encoder
  at 2 kHz (o14033's class): the coefficients fitted against the quantisation's band left a
  low-pass in the residual's low end;
- `prbs500`: a V drive on a PRBS at 500 Hz, ω an 8192-count difference (o14073's): the drive's
  fast response beyond the baseline's two command taps, f⁴·|U|² rising into the colour band's top.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import outsider_classes as fam
import pytest
from scipy.stats import binom

from tvsd.analysis import quantisation, spectral_fit


def _colour_alarms(cls: str, seed: int, n: int, tmp: Path) -> list[tuple[int, float]]:
    """(case seed, colour p) of the family's draws the doctor names `colored_noise`."""
    alarms = []
    for case in fam.v_seeds(seed, n):
        r = fam.run_one(fam.spec_of(cls, case, "none", 0.0), tmp)
        if r["cause"] == "colored_noise":
            alarms.append((case, r["colour_p"]))
    return alarms


# The colour gate is p < 1e-3 per file; among n nulls the count of alarms is then binomial(n, 1e-3)
# at most (the file's other tests only take alarms away), and ≥ 2 of 8 has probability 2.8e-5.
ALLOWED = int(binom.isf(1e-4, 8, 1e-3))  # = 1


@pytest.mark.slow
@pytest.mark.parametrize("cls", ["coarse-quiet", "prbs500-quiet"])
def test_fresh_nulls_of_the_two_classes_are_not_coloured(cls: str, tmp_path: Path) -> None:
    """Eight draws of each class at a quiet vibration (σv 0.1, where the fit's and the drive's
    parts weigh most), seeds not used to trace or to choose anything. integ3 named 4/8 and 3/8
    `colored_noise` (p 3e-17–7e-4 and 2e-52–5e-11); this branch 0/8 and 0/8."""
    alarms = _colour_alarms(cls, 142000, 8, tmp_path)
    assert len(alarms) <= ALLOWED, alarms


def test_the_floor_whitening_whitens_flat_plus_floor() -> None:
    """The AR filter of level + floor(f) makes that spectrum flat where the colour test looks:
    |A(f)|²·S(f) within 2× of its median over the band below the floor's crossing and a decade
    above it (an AR(24) on a 10⁴ rise; a 2× misweighting costs the GLS efficiency, not bias)."""
    rate = 500.0
    level = 1.0

    def floor(f: np.ndarray) -> np.ndarray:  # an f⁴ floor crossing the flat level at 8 Hz
        return np.asarray((np.asarray(f) / 8.0) ** 4)

    ar = spectral_fit.floor_whitening(level, floor, rate)
    f = np.linspace(0.5, 50.0, 400)
    a = np.abs(np.polyval(ar[::-1], np.exp(-2j * np.pi * f / rate))) ** 2
    white = a * (level + floor(f))
    assert np.all(np.abs(np.log(white / np.median(white))) < np.log(2.0))


def test_closed_loop_keeps_the_doctors_fit(tmp_path: Path) -> None:
    """With a recorded reference the command answers the noise: the residual is
    `quantisation.gated`'s, unchanged (an outsider closed-loop file on a 256-count encoder)."""
    prep = fam.coarse_encoder_rows(tmp_path, closed=True)
    n = len(prep.t_rows)
    g = np.random.default_rng(1)
    keep = np.ones(n, dtype=bool)
    keep[n // 3 : n // 3 + 50] = False
    resid, X = g.standard_normal(n), g.standard_normal((n, 4))
    rate = 1.0 / float(np.median(np.diff(prep.t_rows)))
    r, fr = spectral_fit.refit(prep, keep, resid, rate, (X, np.array([1.0, -0.5])))
    q, fq = quantisation.gated(prep, keep, resid, rate, (X, np.array([1.0, -0.5])))
    assert fr is not None and fq is not None
    np.testing.assert_array_equal(r, q)
