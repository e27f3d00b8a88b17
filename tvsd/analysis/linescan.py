"""The resonance test's line scan: a sinusoid at any Fourier frequency of the band, judged through
the periodogram of the whitened residual against its own local level (LineScan), with the
excitation's own lines and the shaft's rotation line left out (excitation_rows, line_scan), and the
winning frequency refined to a fraction of a bin (refine_frequency). The decision
(tvsd.analysis.calibrate) standardises its peak by the null peaks drawn here, like every cause.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from tvsd.analysis.design import Design, resonance_columns
from tvsd.analysis.gls import orth, whiten

RES_MIN_HZ = 1.0
RES_BAND = 0.8  # scan resonance up to this share of the analysis band
FLOOR_HZ = 2.0  # the resonance scan's local spectrum: medians of blocks this wide
NULL_CHUNK = 400  # line-scan null periodograms drawn this many at a time
NULL_CHUNK_VALUES = 2_000_000  # and at most this many ordinates (16 MB per array)


@dataclass(frozen=True)
class LineScan:
    """Where a line fixed in Hz is looked for, and how each periodogram ordinate is judged.

    Each ordinate 2|F|²/n of the whitened residual is measured against the residual's own
    spectrum around it (`local_level`: the medians of FLOOR_HZ blocks, read between their
    centres; the median of an exponential ordinate is ln 2 of its mean), rescaled to the flat
    level the null assumes: the AR whitening leaves the
    spectrum only roughly flat (in closed loop the law shapes it into a bump at the loop's
    bandwidth), and the largest of ~2000 ordinates then sat on the highest stretch, not on a
    line — 37 % of 49 open-loop nulls had a resonance statistic above its null's 90 % point.
    Frequencies where the command itself has a line (a multisine's, identify's reference
    multisine seen through the loop) are left out: a rigid model that misfits the drive's
    response a little leaves a line exactly there, which no torque test can tell from a mode
    (closed-loop nulls named `resonance` at 7.99 Hz, the identify multisine's top line).
    """

    f: np.ndarray  # frequencies of the rfft grid
    scan: np.ndarray  # bool, the ordinates scanned
    width: int  # bins per block of the local level

    def ordinates(self, e: np.ndarray) -> np.ndarray:
        n = len(e)
        pgram = 2.0 * np.abs(np.fft.rfft(e)) ** 2 / n
        flat = 2.0 * float(e @ e) / n  # the mean ordinate of white noise with e's variance
        return pgram * flat / np.maximum(local_level(pgram, self.width), 1e-300 * max(flat, 1e-300))

    def peak(self, e: np.ndarray) -> tuple[float, float]:
        """Largest ΔRSS of a sinusoid at a scanned Fourier frequency, and its frequency."""
        d = np.where(self.scan, self.ordinates(e), -np.inf)
        k = int(np.argmax(d))
        return float(d[k]), float(self.f[k])

    def null_peaks(self, rng: np.random.Generator, boot: int) -> np.ndarray:
        """The same statistic for `boot` white residuals of unit variance: exponential ordinates
        through the same block medians (their own scatter widens the null, and is in it)."""
        if not np.any(self.scan):
            return np.zeros(boot)
        peaks = []
        # In chunks of whole periodograms (the generator's stream, so the draws, do not depend
        # on the split), at most NULL_CHUNK_VALUES ordinates at once: a fixed count of
        # periodograms grows with the record (400 × 450 000 ordinates, 1.4 GB per array, on 1 h).
        chunk = max(1, min(NULL_CHUNK, NULL_CHUNK_VALUES // max(len(self.f), 1)))
        for lo in range(0, boot, chunk):
            # In place (memrate.md): the block and its level are the only block-sized arrays
            # alive; the ratio's temporaries, the scanned part's copy and the previous block's
            # ratio held 5 (76 MiB). The level is read between block centres (res17.md).
            Z = rng.exponential(size=(min(chunk, boot - lo), len(self.f)))
            Z *= 2.0
            level = local_level(Z, self.width)
            np.maximum(level, 1e-300, out=level)
            Z *= 2.0
            Z /= level
            del level
            Z[:, ~self.scan] = -np.inf  # positive ratios: the row's max is the scanned part's
            peaks.append(np.max(Z, axis=1))
            del Z
        return np.concatenate(peaks)


def block_floor(pgram: np.ndarray, width: int) -> np.ndarray:
    """The ordinates' local mean level (along the last axis): the median of each block of
    `width` bins over ln 2, held across the block (blocks, not a running median: the null draws
    400 periodograms, and a running median of them cost 1 s of CPU per analysis)."""
    m = pgram.shape[-1]
    nb = max(m // width, 1)
    edges = np.linspace(0, m, nb + 1).astype(int)
    out = np.empty_like(pgram)
    for lo, hi in itertools.pairwise(edges):
        out[..., lo:hi] = np.median(pgram[..., lo:hi], axis=-1, keepdims=True)
    out /= math.log(2.0)  # in place: a copy of a null block's size less at the null's peak
    return out


def local_level(pgram: np.ndarray, width: int) -> np.ndarray:
    """The ordinates' local mean level (along the last axis): each block's median of `width`
    bins over ln 2 (block_floor) placed at the block's centre, linearly interpolated between the
    centres and held beyond the outer two.

    A block median is the spectrum's level at the block's centre; held across the block it is
    off by the spectrum's slope × the distance from the centre, and where the whitened residual
    still slopes (its lowest hertz, which AR(6) on the rows does not flatten) an ordinate at the
    block's top edge was measured against a level several times too low: an outsider null's
    spectrum rose 12× over its 0–2 Hz block, whose median read a quarter of the level at
    1.82 Hz, and its ordinate there was named `resonance` at z 7.4 (o17067,
    docs/measurements/res17.md). Read between the centres, a linear slope is followed exactly;
    the null's exponential draws go through the same reading."""
    m = pgram.shape[-1]
    nb = max(m // width, 1)
    edges = np.linspace(0, m, nb + 1).astype(int)
    out = np.empty_like(pgram)
    centres = 0.5 * (edges[:-1] + edges[1:] - 1)
    at = np.ceil(centres).astype(int)  # the first bin at or after each centre

    def level(k: int) -> np.ndarray:
        return np.median(pgram[..., edges[k] : edges[k + 1]], axis=-1, keepdims=True) / math.log(2.0)

    # two blocks' medians alive at a time, each slice filled in place: nothing of a block's
    # width or more besides `out` (every block's medians in a list held the null 0.6 MiB above its
    # estimate at 10 min, test_doctor_memory)
    below = level(0)
    out[..., : at[0]] = below
    for k in range(nb - 1):
        above = level(k + 1)
        part = out[..., at[k] : at[k + 1]]
        part[...] = (np.arange(at[k], at[k + 1]) - centres[k]) / (centres[k + 1] - centres[k])
        part *= above - below
        part += below
        below = above
    out[..., at[-1] :] = below
    return out


# ± bins around a declared excitation line: a line of the record's length spans ±1 bin (its main
# lobe); the multisine plays over less than the record (the ramp before, fades), so ±2, the width
# the command's detected lines are left out with.
DECLARED_BINS = 2


def excitation_rows(design: Design) -> list[np.ndarray]:
    """The signals whose lines are not a mode's: the excitation's own (the command in open loop;
    in closed loop the speed reference — the closed-loop command also holds the law's answer to
    every disturbance, a mode's line among them: a 59.8 Hz mode, ordinate 1.9e4 times its local
    level, was skipped because the command answered it; matrix_closed plan seed 0, case 45), and
    the shaft's once-per-revolution signal (sin φ, the imbalance's column): at a steady speed a
    torque locked to the angle is a line at the rotation rate, which a mode there cannot be told
    from, and the imbalance is tested with its own columns (a spinning closed-loop imbalance came
    out as a 20.0003 Hz `resonance` once the reference, which has no line there, replaced the
    command). At a varying speed sin φ has no line: nothing is left out. Cogging's orders are
    not: 24 of them left out the band's low part at scanning speeds (case 45's mode sits on
    the 15th), and a mode there is still weighed against cogging's own test."""
    ref = design.prep.data.speed_reference
    closed = ref is not None and design.rules.lines_of_reference  # off: the command's (ls0, ls1)
    out = [design.prep.band_rows(ref)] if ref is not None and closed else [design.X[:, 0]]
    out += [opt.block[:, 0] for opt in design.options.get("imbalance", [])]
    return out


def line_scan(
    e: np.ndarray, signals: list[np.ndarray], fs: float, f_hi: float, declared: tuple[float, ...] = ()
) -> LineScan:
    """`declared`: the excitation's known lines (`# excitation_hz:`), left out ± DECLARED_BINS
    bins of the record's resolution fs/n whether or not they stand out in the signals: in closed
    loop identify's 8 Hz reference line stood 4.8× its local level in the reference (the steps'
    broadband spectrum), short of the detection below, while the residual held it 23× (seed 62).
    A mode exactly on a declared line cannot be told from the excitation's misfit there."""
    n = len(e)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    width = max(int(FLOOR_HZ / max(float(f[1] - f[0]), 1e-12)), 21)
    scan = (f >= RES_MIN_HZ) & (f <= f_hi)
    near = np.convolve(signal_lines(signals, width, len(f)).astype(float), np.ones(5), mode="same") > 0
    df = float(f[1] - f[0]) if len(f) > 1 else math.inf
    for f_k in declared:
        near |= np.abs(f - f_k) <= DECLARED_BINS * df + 1e-9 * df
    return LineScan(f, scan & ~near, width)


def signal_lines(signals: list[np.ndarray], width: int, bins: int) -> np.ndarray:
    """The rfft bins where any of `signals` has a line: ordinates above the level white noise's
    largest of them passes with probability 1 % (exponential ordinates: ln(N/0.01) times the
    local mean of `width`-bin blocks); `bins`: the residual's rfft length (no signal, no line)."""
    lines = np.zeros(bins, dtype=bool)
    for u in signals:
        pu = np.abs(np.fft.rfft(u - u.mean())) ** 2
        lines |= pu > math.log(len(pu) / 0.01) * block_floor(pu, width)
    return lines


def command_lines_hz(signals: list[np.ndarray], fs: float) -> tuple[float, ...]:
    """The frequencies of the lines `signals` hold (excitation_rows' signals on the kept rows), as
    the line scan detects them: the largest bin of each run of line bins. For the spectral peak
    test, which a multisine's line misfit by the rigid model fools as it fools the line scan (an
    outsider null's 24.9 Hz `resonance`, the multisine's 25 Hz top line, no line declared)."""
    if not signals or len(signals[0]) < 2:
        return ()
    n = len(signals[0])
    f = np.fft.rfftfreq(n, 1.0 / fs)
    lines = signal_lines(signals, max(int(FLOOR_HZ / float(f[1] - f[0])), 21), len(f))
    power = np.zeros(len(f))
    for u in signals:
        power += np.abs(np.fft.rfft(u - u.mean())) ** 2
    out = []
    edges = np.flatnonzero(np.diff(np.concatenate(([0], lines.astype(np.int8), [0]))))
    for lo, hi in zip(edges[::2], edges[1::2], strict=True):
        out.append(float(f[lo + int(np.argmax(power[lo:hi]))]))
    return tuple(out)


def refine_frequency(
    design: Design, f0: float, a: np.ndarray, keep: np.ndarray, Q0: np.ndarray, e0: np.ndarray
) -> float:
    """The peak frequency to a fraction of a bin, by the exact projection on its neighbours.

    ±2 bins, not ±0.5: the periodogram takes the kept rows as one contiguous series, and where
    stuck rows were dropped its peak can sit a bin or two off (65.563 Hz peaked at 65.533; the
    fit at 65.540 drifted 4 rad over 30 s and failed out of sample, seed 6). The statistic and
    its null are the periodogram's, unchanged; only the frequency carried on is refined."""
    T_total = float(design.prep.data.t[-1] - design.prep.data.t[0])
    best_f, best = f0, -1.0
    for f in f0 + np.linspace(-2.0, 2.0, 33) / max(T_total, 1e-9):
        Wq, _ = orth(whiten(resonance_columns(design.prep, float(f)), a, keep), Q0)
        proj = Wq.T @ e0
        v = float(proj @ proj)
        if v > best:
            best_f, best = float(f), v
    return best_f
