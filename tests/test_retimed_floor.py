"""An encoder-difference speed logged late keeps its quantisation floor after dataset.load
re-times it (branches lagref × quantfloor, found in review): the FFT shift by a fractional lag
moves every sample off the count grid, but an all-pass shift moves none of the quantisation's
power, so the step is read on the samples as recorded. Before: `quantisation.floor` → None for
the late file, and its quantisation read as colour again."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tvsd.analysis import quantisation
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.config import load_config
from tvsd.recording.csvfile import write


def _encoder_file(path: Path, late: int) -> Path:
    """A 4096-count encoder at 1 kHz; omega its backward difference, `late` samples late (a
    control thread logging the count difference of the period before)."""
    fs, n, counts = 1000.0, 30_000, 4096
    q = 2 * math.pi / counts
    rng = np.random.default_rng(4)
    t = np.arange(n) / fs
    w = 60.0 + 40.0 * np.sin(2 * np.pi * 0.7 * t) + 15.0 * np.sin(2 * np.pi * 2.3 * t + 1.0)
    w = w + np.convolve(rng.standard_normal(n), np.ones(30) / 30, mode="same") * 5.0
    phi = np.floor(np.cumsum(w) / fs / q) * q
    omega = np.diff(np.concatenate([[0.0], phi])) * fs
    if late:
        omega = np.concatenate([np.full(late, omega[0]), omega[:-late]])
    write(path, t, 0.05 * w + rng.normal(0, 0.1, n), omega, phi, fs, {"encoder_counts_per_rev": counts})
    return path


@pytest.mark.parametrize("late", [0, 1, 2])
def test_an_encoder_difference_keeps_its_floor_whatever_its_timing(tmp_path: Path, late: int) -> None:
    d = load(_encoder_file(tmp_path / f"late{late}.csv", late), load_config())
    assert (late == 0) == ("omega_timing" not in d.meta)  # the late ones are re-timed
    prep = prepare(d, Band())
    keep = np.ones(len(prep.rows(prep.accel)))
    f = np.linspace(1.0, 50.0, 4901)
    reference = load(_encoder_file(tmp_path / "ref.csv", 0), load_config())
    on_time = quantisation.floor(prepare(reference, Band()), keep)
    late_floor = quantisation.floor(prep, keep)
    assert late_floor is not None and on_time is not None
    # The same encoder and step: the floors carry the same power. Compared per octave, not per
    # frequency: the floor is a histogram of sawtooth lines placed by the speed, and a shift of
    # ≤ 2 ms moves single lines across bins while the power in an octave stays (measured: the
    # octaves agree within 7 %, the lowest the least; 10 % allows for the lines at an octave's edge).
    for lo in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        band = (f >= lo) & (f < min(2 * lo, 50.0))
        assert np.isclose(late_floor(f)[band].sum(), on_time(f)[band].sum(), rtol=0.10), lo
