"""The quantisation floor's line placement (tvsd.analysis.quantisation: the lines spread by the
uncertainty of the speed that places them) and the peak test's top edge (noise._flanked);
docs/measurements/peakfix.md."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import quantisation_nulls as qn
from scipy.signal import butter, freqz

from tvsd.analysis import noise, peak
from tvsd.analysis import quantisation as Q


def test_a_staircase_line_beside_the_floors_placement_is_not_a_mode() -> None:
    """A fresh null of the family (seed 1202, case 68 of scripts/bandfloor_peaks.py --mix: 3778
    counts, a staircase at 500 Hz, every row kept): its quantisation line at 10.0 Hz (Q 20) stood
    5.13× the floor, which placed it from the low-passed speed as a sharp line a few hertz away,
    and was named `resonance`. With each harmonic spread by its placement's rms the floor holds
    the line's power where it may be: under PEAK_FLOOR_C (4.19 on the code of this branch)."""
    rng = np.random.default_rng([1202, 68])
    null = dataclasses.replace(qn.draw(rng), profile="staircase")
    assert (null.counts, null.fs) == (3778, 500.0)
    resid, rate, floor = qn.residual(null, rng, gaps=False)
    r = noise.analyse(resid, rate, 1.0, 100.0, floor)
    assert abs(r.peak_hz - 10.0) < 0.5, r.peak_hz  # the same line is the fitted peak
    assert r.peak_over_floor < peak.PEAK_FLOOR_C, r.peak_over_floor
    assert noise.spectral_cause(r, noise.COLOUR_P) != "resonance"


def test_the_placement_error_is_the_floors_own_lines_below_the_speed_low_pass() -> None:
    """At a constant rate of p counts per sample, {p}·fs = 3 Hz, harmonic n of e's sawtooth
    (power q²/(2π²n²)) lies at 3n Hz; differenced (× (2πf)²) each adds 2·(3 Hz)² (counts/s)² to
    the speed's error, through the 5 Hz low-pass forward and back (|H|⁴). The placement's rms is
    the root of that sum; the histogram's bins (1/64 Hz) and sin(πf/fs) ≈ πf/fs at 3n Hz of 1 kHz
    put it within 1 %."""
    fs, step = 1000.0, 1.0
    q = step / fs
    df = 1.0 / Q.SEGMENT_S / Q.OVERSAMPLE
    density = np.zeros(int(fs / 2 / df) + 1)
    for n in range(1, Q.HARMONICS + 1):
        density[round(3.0 * n / df)] += q * q / (2 * math.pi**2 * n * n) / df
    b, a = butter(2, Q.SPEED_HZ / (fs / 2))
    f_lines = 3.0 * np.arange(1, Q.HARMONICS + 1)
    _, h = freqz(b, a, worN=2 * np.pi * f_lines / fs)
    expected = math.sqrt(float(np.sum(2 * 3.0**2 * np.abs(h) ** 4)))
    got = Q.placement_rms(density, q, fs, df, Q.SPEED_HZ)
    assert abs(got / expected - 1.0) < 0.01, (got, expected)


def test_spreading_the_lines_moves_their_power_and_adds_none() -> None:
    """A staircase's speed (three levels, lines at a few hertz): the floor with its lines spread
    holds the same power over [0, fs/2] as without (the normal kernel sums to one and its tails are
    folded back at 0 and fs/2); 0.5 % is the trapezoid rule's on the Hann-smoothed histogram."""
    fs, q = 1000.0, 2 * math.pi / 2000
    speed = np.repeat([10.003, 4.251, 7.7], 10_000) * q * fs  # counts per sample × step
    w = np.ones(len(speed))
    f = np.linspace(0.0, fs / 2, 200_001)
    sharp = np.trapezoid(Q.error_psd(speed, w, q, fs, 4.0)(f), f)
    spread = np.trapezoid(Q.error_psd(speed, w, q, fs, 4.0, Q.SPEED_HZ)(f), f)
    assert abs(spread / sharp - 1.0) < 0.005, (sharp, spread)
    assert abs(sharp / (q * q / 12) - 1.0) < 0.01  # and both are e's q²/12


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
