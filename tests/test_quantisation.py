"""The encoder quantisation's known floor in the colour test (tvsd.analysis.quantisation)."""

from __future__ import annotations

import math

import numpy as np
import quantisation_nulls as qn
from scipy.stats import binom

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
    assert Q.speed_step(w_enc, fs, 1024.0) == 2 * math.pi / 1024 * fs
    assert math.isclose(Q.speed_step(w_enc, fs, None) or 0.0, q * fs, rel_tol=1e-9)
    w_float = np.round(w_enc + g.normal(0.0, 0.05, n), 7)  # period mean + noise, 7 digits
    assert Q.speed_step(w_float, fs, 8192.0) is None
    assert Q.speed_step(w_float, fs, None) is None
    assert Q.speed_step(w_enc, fs, 1000.0) is None  # a declared count ω is not the difference of


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
