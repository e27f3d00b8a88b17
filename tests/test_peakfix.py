"""The peak test's top edge (noise._flanked): the fitted centre inside the bins the test saw;
docs/measurements/peakfix.md."""

from __future__ import annotations

import dataclasses

import numpy as np
import quantisation_nulls as qn

from tvsd.analysis import noise


def test_a_mode_at_the_top_of_the_band_is_named() -> None:
    """A fresh mode of the family (seed 1203, case 60 of scripts/bandfloor_peaks.py --mix --size 20
    --lo-hz 30 --hi-hz 90: a pure tone at 49.62 Hz, 20× the noise, on a staircase, every row
    kept) stands ≈ 66× the floor, but lies within two bins of the band's 50 Hz top: the flank rule
    that asked two bins inside the top held it. Its centre lies inside the bins the test saw."""
    rng = np.random.default_rng([1203, 60])
    null = dataclasses.replace(qn.draw(rng), profile="staircase")
    null = qn.with_mode(null, rng, 20.0, 30.0, 90.0)
    assert abs(null.mode_hz - 49.62) < 0.01, null.mode_hz
    resid, rate, floor = qn.residual(null, rng, gaps=False)
    r = noise.analyse(resid, rate, 1.0, 100.0, floor)
    assert abs(r.peak_hz - null.mode_hz) < 0.5, r.peak_hz  # two Welch bins
    assert noise.spectral_cause(r, noise.COLOUR_P) == "resonance", r


def test_a_peak_above_the_bins_the_test_saw_is_not_flanked() -> None:
    """The top edge: a centre above the bins the peak test saw (a gapped encoder null's 54.7 Hz in
    a 49.8 Hz band) is not a mode the band shows; one on its top bins is; the bottom keeps its two
    bins (a low-frequency rise)."""
    f = np.linspace(0, 125, 3751)  # 1/30 Hz bins: a 30 s record
    df = float(f[1] - f[0])

    def at(hz: float) -> noise.NoiseReport:
        return noise.NoiseReport(
            0.5, 0.0, 1.0, 0.0, 0.1, f, np.ones_like(f), peak_hz=hz, peak_band_hz=(0.5, 49.8)
        )

    assert noise._flanked(at(49.8 - df))
    assert noise._flanked(at(49.8))
    assert not noise._flanked(at(49.8 + df))
    assert not noise._flanked(at(54.7))
    assert not noise._flanked(at(0.5 + df))
