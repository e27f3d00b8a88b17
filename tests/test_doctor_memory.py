"""The doctor's memory grows with the record, by a stated amount per row (docs/measurements/docmem.md).

Before: a 120 s, 2 kHz recording took 1.25 GB peak RSS and a 1 h one did not finish. Two
consumers did not follow the rows: every candidate column was a strided view that kept its
full-rate parent alive (4× the rows' memory), and the resonance scan's null drew 400
periodograms at a time whatever their length (400 × 450 000 ordinates, 1.4 GB per array, on
1 h at 1 kHz).
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from tvsd.analysis import calibrate as C
from tvsd.analysis.dataset import ROTARY, Dataset
from tvsd.analysis.prep import Band, prepare


def _dataset(n: int, fs: float = 1000.0) -> Dataset:
    rng = np.random.default_rng(0)
    t = np.arange(n) / fs
    u = np.repeat(rng.uniform(-3, 3, n // 500 + 1), 500)[:n]
    w = 50.0 + np.cumsum(rng.standard_normal(n)) * 0.01
    return Dataset("mem", t, u, np.cumsum(w) / fs, w, fs, 1.0, 0.0, ROTARY, False)


def test_a_column_of_rows_holds_only_its_rows() -> None:
    """A decimated column is its own array: a view kept the full-rate filtered signal (decim ×
    its size) alive as long as the candidate's block lived."""
    prep = prepare(_dataset(40_000), Band())
    col = prep.band_rows(np.sin(prep.data.position))
    owned = col if col.base is None else col.base
    assert owned.nbytes <= col.nbytes, f"{owned.nbytes} bytes kept for {col.nbytes}"


def test_the_line_scans_null_is_drawn_in_bounded_blocks() -> None:
    """The null's periodograms are drawn at most NULL_CHUNK_VALUES ordinates at a time, so its
    peak allocation does not grow with the record (400 at a time: 400 × ordinates × 8 bytes per
    array, several arrays), and the draws are the ones a single block gives (same stream)."""
    f = np.fft.rfftfreq(400_000, 1 / 250.0)  # 800 s of 250 Hz rows
    scan = C.LineScan(f, (f > 1.0) & (f < 80.0), 1601)
    tracemalloc.start()
    try:
        peaks = scan.null_peaks(np.random.default_rng(3), 40)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # a block of NULL_CHUNK_VALUES float64 ordinates, its floor, its ratio and the scanned part:
    # 4 arrays of 16 MB, with room for the block's medians
    assert peak <= 6 * 8 * C.NULL_CHUNK_VALUES, f"{peak / 2**20:.0f} MiB"
    small = C.LineScan(f[:2001], scan.scan[:2001], 21)
    rng = np.random.default_rng(3)
    E = 2.0 * rng.exponential(size=(40, 2001))
    whole = np.max((E * 2.0 / C._floor(E, 21))[:, small.scan], axis=1)
    assert np.array_equal(small.null_peaks(np.random.default_rng(3), 40), whole)


@pytest.mark.parametrize("boot", [1, 7])
def test_a_short_null_is_unchanged(boot: int) -> None:
    f = np.fft.rfftfreq(1000, 1 / 250.0)
    scan = C.LineScan(f, f > 1.0, 21)
    assert scan.null_peaks(np.random.default_rng(1), boot).shape == (boot,)
