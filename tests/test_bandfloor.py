"""The peak test over the whole band when an encoder's quantisation floor cuts the colour's band
(tvsd.analysis.noise, docs/measurements/bandfloor.md)."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import quantisation_nulls as qn

from tvsd.analysis import noise, peak
from tvsd.analysis import quantisation as Q
from tvsd.analysis.summary import floor_note


def _gated(null: qn.Null, seed: int) -> tuple[noise.NoiseReport, float]:
    every, keep, prep = qn.rows(null, np.random.default_rng(seed))
    rate = null.fs / prep.band.decim
    resid, floor = Q.gated(prep, keep, every, rate)
    return noise.analyse(resid, rate, 1.0, 100.0, floor), rate


def test_a_mode_above_the_floor_crossing_is_named() -> None:
    """A Q-80 mode at 40 Hz, 20× the noise (the outsider's largest size), on an 8192-count encoder
    at 1 kHz, σv 0.1: the floor passes the flat level below 30 Hz, where the peak test stopped
    before (never named); over the whole band, the floor in its model, it is named at its
    frequency (within the Welch resolution's 0.25 Hz × 2), ≈ 19× the floor there."""
    null = qn.Null(8192, 1000.0, "multisine", 8.0, 0.1, 30.0, mode_hz=40.0, mode_q=80.0, mode_size=20.0)
    r, _ = _gated(null, 3)
    assert r.floor_cut_hz is not None and r.floor_cut_hz < 30.0, r.floor_cut_hz  # the band was cut below it
    assert r.colour_band_hz is not None and r.colour_band_hz[1] < 30.0
    assert r.peak_band_hz is not None and r.peak_band_hz[1] == 50.0
    assert noise.spectral_cause(r, 1e-3) == "resonance", (r.peak_hz, r.peak_q, r.peak_over_floor)
    assert abs(r.peak_hz - 40.0) < 0.5


def test_a_staircases_quantisation_line_is_not_a_mode() -> None:
    """A seeded null of the calibration family (seed 4, case 30: 504 counts, a staircase at 1 kHz):
    the quantisation's line at 15.9 Hz stands 4.5× above the floor's model of it, passes every other
    peak gate, and so was named `resonance` with no floor constant; PEAK_FLOOR_C holds it."""
    rng = np.random.default_rng([4, 30])
    null = qn.draw(rng)
    assert (null.counts, null.profile) == (504, "staircase")
    every, keep, prep = qn.rows(null, rng)
    rate = null.fs / prep.band.decim
    resid, floor = Q.gated(prep, keep, every, rate)
    r = noise.analyse(resid, rate, 1.0, 100.0, floor)
    assert 1.0 < r.peak_over_floor < peak.PEAK_FLOOR_C  # the line is there, above the floor
    assert noise.spectral_cause(r, 1e-3) is None


def test_without_a_floor_both_tests_see_the_same_band() -> None:
    """A tach's or tvsd's own speed (no floor): one band, no cut, the peak unbounded by a floor
    (the code path before this change)."""
    g = np.random.default_rng(1)
    r = noise.analyse(g.standard_normal(7500), 250.0, 1.0, 100.0)
    assert r.colour_band_hz == r.peak_band_hz == (0.5, 50.0)
    assert r.floor_cut_hz is None and math.isinf(r.peak_over_floor)


def test_the_sentence_says_where_the_floor_cut_the_band() -> None:
    f = np.linspace(0, 125, 501)
    cut = noise.NoiseReport(
        0.5, 0.0, 1.0, 0.0, 0.1, f, np.ones_like(f),
        colour_band_hz=(0.5, 17.25), peak_band_hz=(0.5, 50.0), floor_cut_hz=17.5,
    )  # fmt: skip
    text = floor_note(SimpleNamespace(noise=cut))  # type: ignore[arg-type]
    assert text is not None and "17.5 Hz" in text and "17.2 Hz" in text and "50 Hz" in text
    whole = noise.NoiseReport(0.5, 0.0, 1.0, 0.0, 0.1, f, np.ones_like(f), peak_band_hz=(0.5, 50.0))
    assert floor_note(SimpleNamespace(noise=whole)) is None  # type: ignore[arg-type]


def test_a_peak_at_either_edge_of_the_tested_band_is_not_flanked() -> None:
    """A Lorentzian at the band's top fits the quantisation floor's steep rise there as well as a
    mode (a gapped encoder null's fitted 'mode' at 54.7 Hz, outside its band): at the top the
    centre must lie inside the bins the test saw; two bins inside the bottom (peakfix: two bins
    inside the top too lost 3 of 56 modes at 49.6–50 Hz and held no null in 1213)."""
    f = np.linspace(0, 125, 3751)  # 1/30 Hz bins: a 30 s record
    df = float(f[1] - f[0])

    def at(hz: float) -> noise.NoiseReport:
        return noise.NoiseReport(
            0.5, 0.0, 1.0, 0.0, 0.1, f, np.ones_like(f), peak_hz=hz, peak_band_hz=(0.5, 49.8)
        )

    assert noise._flanked(at(30.0))
    assert noise._flanked(at(49.8 - 2 * df))
    assert noise._flanked(at(49.8 - df))
    assert not noise._flanked(at(49.8 + df))
    assert not noise._flanked(at(54.7))
    assert not noise._flanked(at(0.5 + df))


def test_a_line_fitted_narrower_than_a_bin_is_judged_by_its_height_on_the_bins() -> None:
    """A fresh null of the family (seed 1201, case 62 of scripts/bandfloor_peaks.py --mix: 1152
    counts, a staircase at 500 Hz, every row kept): its quantisation line at 41.6 Hz stands
    3.6–3.8× the floor on its two bins (under PEAK_FLOOR_C), but the Lorentzian fitted it with
    Q 1.5e8, its tails on those bins and its top 10¹² × the floor; the top's power over the
    window's 1.5 bins read 2.5e6× the floor and named `resonance`. The height is the model's on
    the bins."""
    rng = np.random.default_rng([1201, 62])
    null = dataclasses.replace(qn.draw(rng), profile="staircase")
    assert (null.counts, null.fs) == (1152, 500.0)
    resid, rate, floor = qn.residual(null, rng, gaps=False)
    r = noise.analyse(resid, rate, 1.0, 100.0, floor)
    assert abs(r.peak_hz - 41.6) < 0.25  # the line is the peak the test found
    assert 1.0 < r.peak_over_floor < peak.PEAK_FLOOR_C, (r.peak_q, r.peak_over_floor)
    assert noise.spectral_cause(r, 1e-3) is None


def test_the_seen_height_of_a_resolved_peak_is_its_top() -> None:
    """A peak wider than the window (Q 20 at 40 Hz: 1 Hz half-power width, 4 bins) shows its top
    on the bin at its centre; a line at a bin's centre narrower than the window shows its power
    over 1.5 bins; one between bins, only its tails."""
    fw = np.arange(0.5, 50.01, 0.25)
    enbw = 1.5 * 0.25
    assert peak.seen_height(fw, 40.0, 20.0, 7.0, enbw) == 7.0
    line = peak.seen_height(fw, 40.0, 1e6, 7.0, enbw)
    assert math.isclose(line, 7.0 * math.pi * 40.0 / 2e6 / enbw)
    tails = peak.seen_height(fw, 40.125, 1e8, 7.0, enbw)
    assert tails < 1e-6 * line
