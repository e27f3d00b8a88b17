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
from tvsd.analysis import linescan as L
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
    scan = L.LineScan(f, (f > 1.0) & (f < 80.0), 1601)
    tracemalloc.start()
    try:
        scan.null_peaks(np.random.default_rng(3), 40)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # a block of NULL_CHUNK_VALUES float64 ordinates, its floor, its ratio and the scanned part:
    # 4 arrays of 16 MB, with room for the block's medians
    assert peak <= 6 * 8 * L.NULL_CHUNK_VALUES, f"{peak / 2**20:.0f} MiB"
    small = L.LineScan(f[:2001], scan.scan[:2001], 21)
    rng = np.random.default_rng(3)
    E = 2.0 * rng.exponential(size=(40, 2001))
    whole = np.max((E * 2.0 / L.local_level(E, 21))[:, small.scan], axis=1)
    assert np.array_equal(small.null_peaks(np.random.default_rng(3), 40), whole)


@pytest.mark.parametrize("boot", [1, 7])
def test_a_short_null_is_unchanged(boot: int) -> None:
    f = np.fft.rfftfreq(1000, 1 / 250.0)
    scan = L.LineScan(f, f > 1.0, 21)
    assert scan.null_peaks(np.random.default_rng(1), boot).shape == (boot,)


def _null_gram_stacked(G: np.ndarray, e: np.ndarray) -> np.ndarray:
    """null_gram as it was (integ3 8d9900c): G stacked, its DFT, the weighted DFT, its conjugate."""
    n = G.shape[0]
    S = C.residual_spectrum(e, C.SPECTRUM_BINS, None)
    F = np.fft.rfft(G, axis=0)
    w = np.full(F.shape[0], 2.0)
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    Fw = F * (w * S)[:, None]
    return np.real(Fw.conj().T @ F) / n


@pytest.mark.parametrize("n", [3000, 3001])
def test_null_gram_from_blocks_is_the_stacked_ones_bit_for_bit(n: int) -> None:
    """The blocks transformed one by one give the gram of G stacked exactly (the bootstrap's
    draws pass through its eigendecomposition, which amplifies round-off: BLAS's thread count
    moved z by ~1 %), and the peak holds two DFT-sized arrays instead of five."""
    rng = np.random.default_rng(2)
    e = np.convolve(rng.standard_normal(n), [1.0, 0.6, 0.3], mode="same")
    blocks = [rng.standard_normal((n, k)) for k in (2, 1, 5, 2)]
    want = _null_gram_stacked(np.column_stack(blocks), e)
    got = C.null_gram(list(blocks), e)
    assert np.array_equal(got, want)
    tracemalloc.start()
    try:
        listed = [rng.standard_normal((n, 1)) for _ in range(40)]
        tracemalloc.reset_peak()
        base, _ = tracemalloc.get_traced_memory()
        C.null_gram(listed, e)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # G is 40·n·8 bytes; its DFT the same in complex (n/2 + 1 rows): two of those at the peak,
    # plus the spectrum's few n-long vectors; five were held before
    g_bytes = 40 * n * 8
    assert peak - base <= 2.6 * g_bytes, f"{(peak - base) / g_bytes:.2f} × G"


def test_a_recording_too_long_for_the_memory_is_refused_in_one_line() -> None:
    """1 h at 2 kHz with 2 GiB free: refused before the analysis (exit 2), saying what it needs,
    what is free and how many minutes would fit — not killed by the kernel part-way."""
    from tvsd.analysis import memory
    from tvsd.errors import DataFileError

    long = _dataset(2000 * 3600, fs=2000.0)
    with pytest.raises(DataFileError) as err:
        memory.check(long, Band(), available=2048.0)
    line = str(err.value)
    assert "\n" not in line and "60.0 min at 2000 Hz" in line and "at most" in line, line
    fit = float(line.split("at most ")[1].split(" min")[0])
    # the stretch it proposes passes the same check
    memory.check(_dataset(int(2000 * 60 * fit), fs=2000.0), Band(), available=2048.0)
    memory.check(_dataset(60_000), Band(), available=2048.0)  # 60 s at 1 kHz: ~330 MiB


def test_the_estimate_grows_linearly_with_the_record() -> None:
    """Above the interpreter and the line scan's null (bounded: within 3 % for 1 and 10 min), the
    estimate is copies of rows × columns: ten minutes cost ten times one minute's."""
    from tvsd.analysis import memory

    def grows(m: int) -> float:
        n = 60_000 * m
        return memory.estimate_mib(n, 1000.0, Band()) - memory.BASE_MIB - memory.null_mib(n, Band())

    assert grows(10) == pytest.approx(10 * grows(1), rel=1e-3)
    assert memory.null_mib(600_000, Band()) == pytest.approx(memory.null_mib(60_000, Band()), rel=0.03)


@pytest.mark.parametrize("n", [20_000, 60_000, 600_000])
def test_the_estimate_holds_the_line_scans_null(n: int) -> None:
    """memory.null_mib is what LineScan.null_peaks holds at its peak (tracemalloc counts numpy's
    buffers exactly): growing with the rows below the block's bound (20 s at 1 kHz), at the bound
    above. Within 0.5 MiB: the bound is the blocks' arrays, the rest is the block medians'
    slices (chunk × width floats, 0.13 MiB at 400 × 41, twice while np.median partitions) and
    the peaks (measured 0.06–0.18 MiB; the 1 % this test allowed of the 5-block null was
    0.76 MiB). Before, the estimate left the null out (61 MiB, 30 at 20 s) and the doctor's own
    allocation at 20 s, 56 MiB, was twice its estimate (memflake.md)."""
    from tvsd.analysis import memory

    f = np.fft.rfftfreq(memory.rows(n, Band()), 1 / 250.0)
    scan = L.LineScan(f, (f > 1.0) & (f < 80.0), 41)
    tracemalloc.start()
    try:
        scan.null_peaks(np.random.default_rng(3), C.BOOTSTRAP)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak / 2**20 == pytest.approx(memory.null_mib(n, Band()), abs=0.5)


def _null_peaks_as_before(scan: L.LineScan, rng: np.random.Generator, boot: int) -> np.ndarray:
    """LineScan.null_peaks as it was (integ3 ec4d41d, with res17's level between block centres):
    each block's ratio as new arrays."""
    chunk = max(1, min(L.NULL_CHUNK, L.NULL_CHUNK_VALUES // len(scan.f)))
    peaks = []
    for lo in range(0, boot, chunk):
        E = 2.0 * rng.exponential(size=(min(chunk, boot - lo), len(scan.f)))
        Z = E * 2.0 / np.maximum(L.local_level(E, scan.width), 1e-300)
        peaks.append(np.max(Z[:, scan.scan], axis=1))
    return np.concatenate(peaks)


@pytest.mark.parametrize("n", [20_000, 600_000])
def test_the_line_scans_null_holds_two_blocks_and_draws_the_same_bits(n: int) -> None:
    """The null's ratio is formed in place: at its peak the block and its floor (2 blocks' size,
    + the medians' slices: 0.5 MiB), not 5 (the ratio's temporaries, the scanned part's copy and
    the previous block's ratio alive while the next was drawn: 38 MiB at 20 s of 1 kHz, 76 at
    the bound; fails on ec4d41d). The same operations in the same order: the draws are the old
    code's bit for bit, so no decision moves."""
    from tvsd.analysis import memory

    f = np.fft.rfftfreq(memory.rows(n, Band()), 1 / 250.0)
    scan = L.LineScan(f, (f > 1.0) & (f < 80.0), 41)
    block_mib = 8.0 * min(L.NULL_CHUNK, L.NULL_CHUNK_VALUES // len(f)) * len(f) / 2**20
    tracemalloc.start()
    try:
        got = scan.null_peaks(np.random.default_rng(5), C.BOOTSTRAP)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak / 2**20 <= 2 * block_mib + 0.5, f"{peak / 2**20 / block_mib:.2f} blocks"
    assert np.array_equal(got, _null_peaks_as_before(scan, np.random.default_rng(5), C.BOOTSTRAP))
