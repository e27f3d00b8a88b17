"""Review of the session's merged doctor (docs/measurements/review6.md): defects at the seams."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import outsider_classes as fam
import pytest

from tvsd.analysis import spectral_fit
from tvsd.analysis.gls import clear_memory
from tvsd.analysis.prep import Band, prepare


def test_the_refit_ignores_the_rows_the_doctor_left_out(tmp_path: Path) -> None:
    """Open loop on a 256-count encoder: refit whitens with AR(FLOOR_AR_ORDER), longer than the
    doctor's AR whose memory `keep` was cleared for. The residual on the rows left out (the shaft
    stuck: the model does not hold there) must not reach the rows kept through that longer
    filter's memory. Changed there by 1e3× the residual's scale, the rows kept may move only by
    the solve's rounding (relative 1e-9: the normal equations' condition number squared, ~1e6,
    times float64's 1e-16 is 1e-10)."""
    prep = fam.coarse_encoder_rows(tmp_path, closed=False)
    n = len(prep.t_rows)
    g = np.random.default_rng(3)
    moving = np.ones(n, dtype=bool)
    moving[n // 3 : n // 3 + 50] = False
    ar = np.array([1.0, -0.5])
    keep = clear_memory(moving, len(ar) - 1)
    resid, X = g.standard_normal(n), g.standard_normal((n, 4))
    rate = 1.0 / float(np.median(np.diff(prep.t_rows)))
    r0, f0 = spectral_fit.refit(prep, keep, resid, rate, (X, ar))
    assert f0 is not None  # the floor's AR(48) is the one under test
    stuck = resid.copy()
    stuck[~moving] += 1e3
    r1, _ = spectral_fit.refit(prep, keep, stuck, rate, (X, ar))
    np.testing.assert_allclose(r1[keep], r0[keep], rtol=0, atol=1e-9 * float(np.std(r0[keep])))


def _white_rows(fs: float, seconds: float, seed: int) -> tuple[np.ndarray, float, float]:
    """A white acceleration at the full rate `fs` as the doctor's residual carries it: the speed
    its running sum, the rows the acceleration column's (band filter, central difference,
    anti-alias, decimation: tvsd.analysis.rowgain's path). The rows, their rate, the band's corner."""
    from tvsd.analysis.dataset import ROTARY, Dataset

    n = int(seconds * fs)
    g = np.random.default_rng(seed)
    u = np.repeat(g.uniform(-1, 1, n // int(fs) + 1), int(fs))[:n]
    speed = np.cumsum(g.standard_normal(n)) / fs
    data = Dataset("white", np.arange(n) / fs, u, np.cumsum(speed) / fs, speed, fs, 1.0, 0.0, ROTARY, False)
    prep = prepare(data, Band())
    return prep.rows(prep.accel), 1.0 / float(np.median(np.diff(prep.t_rows))), prep.band.cutoff_hz


def test_a_white_residual_of_a_slow_file_is_not_coloured() -> None:
    """At 100 Hz the band's corner is 40 Hz (0.4·fs) and its half, 20 Hz, lies beyond the rows'
    Nyquist (12.5 Hz at decim 4): the colour test's band ran into the anti-alias filter's
    roll-off (its corner 0.8 of the rows' Nyquist, 10 Hz), which a flat spectrum falling there
    fits as a low-pass. A white residual of 120 s (seeded): colour p 9e-52 before (six seeds:
    all < 1e-49), 0.11 after (six seeds 0.00087–0.39: the sinc² droop the colour shape does not
    model remains, review6.md). The gate is p < COLOUR_P."""
    from tvsd.analysis.noise import COLOUR_P, analyse

    rows, rate, cutoff = _white_rows(100.0, 120.0, 0)
    report = analyse(rows, rate, 1.0, cutoff)
    assert report.colour_band_hz is not None and report.colour_band_hz[1] <= 0.8 * rate / 2
    assert report.colour_p >= COLOUR_P, report.colour_p


def test_a_white_residual_at_1khz_keeps_its_band() -> None:
    """At 1 kHz the anti-alias corner (100 Hz) is far above the band's half (50 Hz): the colour
    band is unchanged, 0.5 Hz to the last bin at or under 50 Hz."""
    from tvsd.analysis.noise import analyse

    rows, rate, cutoff = _white_rows(1000.0, 60.0, 6)
    report = analyse(rows, rate, 1.0, cutoff)
    assert report.colour_band_hz is not None
    assert report.colour_band_hz[0] == pytest.approx(0.5) and 49.7 < report.colour_band_hz[1] <= 50.0
