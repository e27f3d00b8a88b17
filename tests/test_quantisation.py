"""The encoder quantisation's known floor in the colour test (tvsd.analysis.quantisation)."""

from __future__ import annotations

import math

import numpy as np
import quantisation_nulls as qn
from scipy.stats import binom

from tvsd.analysis import count_grid
from tvsd.analysis import quantisation as Q
from tvsd.analysis.dataset import ROTARY, Dataset
from tvsd.analysis.noise import _welch, colour_test
from tvsd.analysis.prep import Band, prepare


def test_the_speeds_grid_is_read_from_the_header_or_the_data() -> None:
    """An encoder difference lies on s = 2π/N·fs; a tachometer or tvsd's own period-mean speed
    with its measurement noise (which `tvsctl sim record` writes beside a declared 8192-count
    encoder) is on no grid, so the floor is not theirs."""
    g = np.random.default_rng(3)
    fs, n = 1000.0, 20000
    q = 2 * math.pi / 1024
    phi = np.cumsum(30.0 + 10.0 * np.sin(np.arange(n) / fs * 2.0)) / fs  # 3–7 counts per sample
    counts = np.floor(phi / q)
    w_enc = np.diff(np.concatenate([[0.0], counts])) * q * fs
    assert count_grid.speed_step(w_enc, fs, 1024.0) == 2 * math.pi / 1024 * fs
    assert math.isclose(count_grid.speed_step(w_enc, fs, None) or 0.0, q * fs, rel_tol=1e-9)
    w_float = np.round(w_enc + g.normal(0.0, 0.05, n), 7)  # period mean + noise, 7 digits
    assert count_grid.speed_step(w_float, fs, 8192.0) is None
    assert count_grid.speed_step(w_float, fs, None) is None
    assert count_grid.speed_step(w_enc, fs, 1000.0) is None  # a declared count ω is not the difference of


def test_a_speed_spread_over_many_counts_gives_the_white_floor() -> None:
    """At a count rate swept over many counts per sample the sawtooth's lines fill [0, fs/2]
    evenly: e is white, q²/12, a one-sided density q²/(6·fs). The histogram's own granularity
    (64 harmonics, 0.016 Hz bins) is smoothed by the Hann kernel; 5 Hz averages within 3 %."""
    fs, q = 1000.0, 2 * math.pi / 512
    speed = np.linspace(0.0, 30.0 * q * fs, 200_000)  # 0–30 counts per sample
    psd = Q.error_psd(speed, np.ones(len(speed)), q, fs, 4.0)
    level = psd(np.linspace(5.0, 495.0, 4900)).reshape(-1, 49).mean(axis=1)  # 5 Hz averages
    assert np.all(np.abs(level / (q * q / (6 * fs)) - 1.0) < 0.03), level / (q * q / (6 * fs))


def test_the_floor_is_the_quantisations_spectrum_in_the_rows() -> None:
    """No vibration, a multisine speed over 0–12 counts per sample: the residual rows are the
    quantisation alone, through the doctor's chain. Their Welch spectrum over 10–50 Hz (160 bins,
    ≈ 7 effective segments: a bin's relative sd 0.38, ≈ 84 independent bins → the mean's sd
    ≈ 0.04) matches the floor to 4 sd."""
    null = qn.Null(1024, 1000.0, "multisine", 12.0, 1e-4, 30.0)
    resid, rate, floor = qn.residual(null, np.random.default_rng(11))
    assert floor is not None
    f, p, _ = _welch(resid, rate)
    m = (f >= 10.0) & (f <= 50.0)
    ratio = float(np.mean(p[m] / floor(f[m])))
    assert abs(ratio - 1.0) < 0.17, ratio


def test_encoder_difference_nulls_are_not_colour() -> None:
    """24 seeded nulls of the family (256–8192 counts, 500–2000 Hz, staircases included):
    without the floor most are `colored_noise` at the doctor's p < 1e-3; with it the count stays
    within binomial(24, 1e-3)'s 99.9 % point (1)."""
    rng = np.random.default_rng(2)
    ps, before = [], []
    for _ in range(24):
        null = qn.draw(rng, seconds=20.0)
        resid, rate, floor = qn.residual(null, rng)
        ps.append(colour_test(resid, rate, 100.0, floor)[1])
        before.append(colour_test(resid, rate, 100.0, None)[1])
    assert np.count_nonzero(np.array(before) < 1e-3) >= 12  # the problem is there
    assert np.count_nonzero(np.array(ps) < 1e-3) <= binom.ppf(0.999, 24, 1e-3)


def test_a_colour_above_the_floor_is_still_seen() -> None:
    """A 20 ms OU colour (the outsider's 20×) at σv 0.5 on a 4096-count encoder at 1 kHz: the
    floor passes the vibration's level only near the band's top, so the colour stays p < 1e-3."""
    null = qn.Null(4096, 1000.0, "multisine", 10.0, 0.5, 30.0, colour_tau_s=0.02)
    resid, rate, floor = qn.residual(null, np.random.default_rng(5))
    assert colour_test(resid, rate, 100.0, floor)[1] < 1e-3


def test_no_floor_for_a_speed_not_measured_or_a_linear_axis() -> None:
    n, fs = 4000, 1000.0
    t = np.arange(n) / fs
    data = Dataset("x", t, np.zeros(n), 3 * t, None, fs, 1.0, 0.0, ROTARY, False)
    assert Q.floor(prepare(data, Band()), np.ones(10, dtype=bool)) is None


def test_the_edge_ramp_is_zero_in_the_gaps_and_one_away_from_them() -> None:
    keep = np.ones(200, dtype=bool)
    keep[100:110] = False
    w = Q.edge_taper(keep, 100.0, 0.1)  # 10 rows of ramp
    assert np.all(w[100:110] == 0.0)
    assert np.all(w[:90] == 1.0) and np.all(w[120:] == 1.0)  # the record's ends are no edges
    assert np.all(np.diff(w[90:100]) < 0) and np.all(np.diff(w[110:120]) > 0)
    assert np.all(Q.edge_taper(np.ones(50, dtype=bool), 100.0) == 1.0)


def test_a_gaps_hard_edge_does_not_leak_the_quantisation() -> None:
    """The doctor leaves the rows where the shaft is stuck out of the residual. A 256-count
    encoder at 1 kHz, fast steps up to 2 counts per sample through zero: with hard edges at the
    gaps the quantisation's f⁴ power leaks into the lowest bins and 2 of these 12 seeded nulls
    were `colored_noise` (p 1.6e-4, 8.3e-5; the outsider's o07000 and o07022 were too). Ramped as
    the doctor now passes them (quantisation.gated), the count stays within binomial(12, 1e-3)'s
    99.9 % point (1)."""
    null = qn.Null(256, 1000.0, "steps", 2.0, 0.3, 20.0)
    hard, ramped = [], []
    for seed in range(12):
        every, keep, prep = qn.rows(null, np.random.default_rng(seed))
        rate = null.fs / prep.band.decim
        hard.append(colour_test(np.where(keep, every, 0.0), rate, 100.0, Q.floor(prep, keep))[1])
        resid, floor = Q.gated(prep, keep, every, rate)
        ramped.append(colour_test(resid, rate, 100.0, floor)[1])
    assert np.count_nonzero(np.array(hard) < 1e-3) >= 2  # the problem is there
    assert np.count_nonzero(np.array(ramped) < 1e-3) <= binom.ppf(0.999, 12, 1e-3)


def test_without_a_count_difference_the_rows_pass_as_they_were() -> None:
    """A speed on no grid (a tachometer, tvsd's own): no floor and no ramp (main's path)."""
    n, fs = 20000, 1000.0
    g = np.random.default_rng(4)
    t = np.arange(n) / fs
    w = 50.0 * np.sin(2 * np.pi * 0.3 * t) + g.normal(0.0, 0.1, n)
    data = Dataset("x", t, np.zeros(n), np.cumsum(w) / fs, w, fs, 1.0, 0.0, ROTARY, False)
    prep = prepare(data, Band())
    resid = g.standard_normal(len(prep.rows(prep.speed)))
    keep = np.abs(prep.rows(prep.speed)) > 1.0
    seen, floor = Q.gated(prep, keep, resid, 250.0)
    assert floor is None
    assert np.array_equal(seen, np.where(keep, resid, 0.0))


def test_an_undeclared_encoders_printed_speed_is_on_its_grid() -> None:
    """An 8192-count encoder's difference at 1 kHz up to ~110 rad/s (143 counts per sample),
    printed as the CSV prints it (7 significant digits): the smallest gap of two printed levels is
    off by up to 5e-5 rad/s, which at the 143rd count is 0.009 of a step, past the grid's 1e-3
    tolerance. The step is read from every level (the outsider's undeclared-encoder nulls o13033,
    o13072 had no floor and were `colored_noise`); the CSV's rounding bounds the error at 1e-6."""
    fs, counts = 1000.0, 8192
    q = 2 * math.pi / counts
    t = np.arange(30000) / fs
    phi = np.cumsum(60.0 + 50.0 * np.sin(2 * np.pi * 0.3 * t)) / fs
    w = np.diff(np.concatenate([[0.0], np.floor(phi / q)])) * q * fs
    printed = np.array([float(f"{x:.7g}") for x in w])
    step = count_grid.speed_step(printed, fs, None)
    assert step is not None
    assert math.isclose(step, q * fs, rel_tol=1e-6)
