"""The peak test through the rows' filters, to the band filter's corner (tvsd.analysis.rowgain;
docs/measurements/peakband.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import outsider_bench as ob
import pytest
from scipy.signal import welch

from tvsd.analysis.dataset import Dataset, Units
from tvsd.analysis.prep import Band, prepare
from tvsd.analysis.rowgain import PEAK_GAIN_MIN, peak_top, rows_gain

TVSCTL = str(Path(sys.executable).parent / "tvsctl")


def _white(fs: float, seconds: float) -> Dataset:
    """An integrated white acceleration as the measured speed (the residual's noise path)."""
    rng = np.random.default_rng(7)
    n = int(seconds * fs)
    speed = np.cumsum(rng.standard_normal(n)) / fs
    units = Units("rad", "rad/s", "rad/s^2", "N*m", "kg*m^2", "rotary")
    return Dataset(
        "white", np.arange(n) / fs, np.zeros(n), np.cumsum(speed) / fs, speed, fs, 1.0, 0.0, units, False
    )


@pytest.mark.parametrize("fs", [1000.0, 2000.0])
def test_the_gain_is_white_noise_through_prepared(fs: float) -> None:
    """G(f) against the Welch spectrum of a white acceleration through Prepared's own filters
    (band filter, central difference, anti-alias, decimation): 400 s gives 199 Hann segments,
    each bin's estimate χ² with ≈ 2·199/2.1 dof (effective segments), so 4 Hz averages (16
    bins) scatter ±2 %; 6 % is three standard deviations. The top sits at the filter's corner."""
    prep = prepare(_white(fs, 400.0), Band())
    rate = fs / prep.band.decim
    f, p = welch(prep.rows(prep.accel), fs=rate, nperseg=int(4 * rate))
    g = rows_gain(prep)
    level = np.median(p[(f > 0.5) & (f < 40)] / g(f[(f > 0.5) & (f < 40)]))
    for f0 in (50.0, 62.0, 75.0, 85.0, 95.0):
        k = (f > f0 - 2) & (f < f0 + 2)
        assert abs(np.mean(p[k]) / level / np.mean(g(f[k])) - 1) < 0.06, f0
    top = peak_top(g, f)
    assert 97.0 <= top <= 100.0  # G(100 Hz) = ¼ (Butterworth) × the difference's and Chebyshev's < 1
    assert g(np.array([top]))[0] >= PEAK_GAIN_MIN


def _analyze(path: Path) -> dict:
    p = subprocess.run([TVSCTL, "analyze", str(path), "--json"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


@pytest.mark.slow
def test_a_mode_at_80_hz_in_a_1_khz_file_is_named(tmp_path: Path) -> None:
    """An outsider recording (1 kHz, 20 s, a tachometer at 300 Hz, multisine on a duty drive) with
    a noise-driven mode at 80 Hz, Q 100, 20× the noise: the peak test stopped at 49.8 Hz (half the
    band filter's corner) and the file was `none`; through the filters' gain it sees to 98.3 Hz."""
    s = ob.draw(91101, "resonance", 20.0, closed=False)
    s.seconds, s.fs = 20.0, 1000.0
    s.sensor["omega"], s.sensor["tach_fc_hz"] = "tach", 300.0
    s.truth["frequency_hz"], s.truth["q"] = 80.0, 100.0
    path = tmp_path / f"{s.name}.csv"
    ob.write(path, s, ob.make(s))
    got = _analyze(path)
    assert got["cause"] == "resonance", got["cause"]
    assert got["noise"]["band_tested_hz"]["peak"][1] > 95.0
    assert abs(got["effect"]["frequency_hz"] - 80.0) < 1.0  # four 0.25 Hz Welch bins


NULL_SEEDS = [91101, 91102, 91103, 91104]


@pytest.mark.slow
@pytest.mark.parametrize("seed", NULL_SEEDS)
def test_1_khz_nulls_stay_none(tmp_path: Path, seed: int) -> None:
    """Outsider nulls at 1 kHz (20 s; the generator's own sensor, drive and excitation): none
    names a mode in the band the peak test gained (49.8–98.3 Hz). Each null is a fixed seed, so
    a pass is deterministic; the false-alarm rate is measured in docs/measurements/peakband.md."""
    s = ob.draw(seed, "none", 0.0, closed=False)
    s.seconds, s.fs = 20.0, 1000.0
    path = tmp_path / f"{s.name}.csv"
    ob.write(path, s, ob.make(s))
    got = _analyze(path)
    assert got["noise"]["band_tested_hz"]["peak"][1] > 95.0
    assert got["cause"] == "none", got["cause"]
