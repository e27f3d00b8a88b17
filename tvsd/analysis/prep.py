"""Signals for the inverse (equation-error) model, the way IDIM-LS prepares them.

Speed and acceleration come from a zero-phase Butterworth low-pass (of the measured speed, or of
the position when no speed is measured) and central differences. Every column of the regression,
and the drive effort it is compared with, is then decimated with the same zero-phase anti-alias
filter ("parallel decimation"), so the equation holds in the band kept and the samples left are
nearly independent (their spacing is about the inverse of the band).
EMPS' published reference uses 100 Hz and decimation by 10 (Janot et al. 2019); for the scanning
aperture the band must hold lines at a few times the rotation rate, so decimation is by 4
(250 Hz, anti-alias corner 100 Hz).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np
from scipy.signal import butter, cheby1, filtfilt

from tvsd.analysis.dataset import Dataset
from tvsd.errors import DataFileError


@dataclass(frozen=True)
class Band:
    cutoff_hz: float = 100.0
    decim: int = 4
    order: int = 4


EMPS_BAND = Band(cutoff_hz=100.0, decim=10)


# the decimation's anti-alias filter's corner, as a share of the rows' Nyquist frequency
ANTIALIAS_CORNER = 0.8


@cache
def antialias(q: int) -> tuple[np.ndarray, np.ndarray]:
    b, a = cheby1(8, 0.05, ANTIALIAS_CORNER / q)
    return np.asarray(b), np.asarray(a)


@dataclass(frozen=True)
class Prepared:
    """Full-rate filtered signals of one dataset, and the decimation that turns columns into rows."""

    data: Dataset
    band: Band
    speed: np.ndarray  # filtered, full rate
    accel: np.ndarray
    trim: int  # samples dropped at each end (filter edge transients)
    b: np.ndarray  # the low-pass (Butterworth) coefficients
    a: np.ndarray

    def lowpass(self, column: np.ndarray) -> np.ndarray:
        """The band filter every column goes through. With a measured speed the acceleration is
        its central difference, i.e. ω̇ averaged over ±1 sample; the [1, 2, 1]/4 average gives
        every other column that same averaging (exact for piecewise-linear signals), so a step in
        the command does not ring in the residual."""
        x = filtfilt(self.b, self.a, column)
        if self.data.speed is not None:
            x = np.convolve(x, [0.25, 0.5, 0.25], mode="same")
        return x

    def band_rows(self, column: np.ndarray) -> np.ndarray:
        """Rows of a column not yet low-passed (the command, functions of φ or t, of sgn ω):
        the same filter as the speed, so both sides of the equation see the same band."""
        return self.rows(self.lowpass(column))

    def decimate(self, column: np.ndarray) -> np.ndarray:
        """One full-rate column at the rows' rate, ends not trimmed."""
        if self.band.decim > 1:  # scipy's decimate(ftype="iir", zero_phase=True), its filter designed once
            b, a = antialias(self.band.decim)
            column = filtfilt(b, a, column)[:: self.band.decim]
        return column

    def rows(self, column: np.ndarray) -> np.ndarray:
        """Parallel-decimate one full-rate column into regression rows."""
        column = self.decimate(column)
        keep = self.trim // self.band.decim
        # A copy, not a view: a strided view keeps the whole full-rate array alive, and every
        # candidate column is one (4× the rows' memory: 1.1 GB of a 120 s, 2 kHz analysis).
        return column[keep : len(column) - keep].copy()

    @property
    def t_rows(self) -> np.ndarray:
        """Times of the rows: subsampled, not filtered (filtering a ramp bends its ends)."""
        t = self.data.t[:: self.band.decim]
        keep = self.trim // self.band.decim
        return t[keep : len(t) - keep]


def prepare(data: Dataset, band: Band) -> Prepared:
    fs = data.sample_rate_hz
    cutoff = min(band.cutoff_hz, 0.4 * fs)
    b, a = butter(band.order, cutoff / (fs / 2))
    dt = 1.0 / fs
    if data.speed is not None:
        filtered = filtfilt(b, a, data.speed)
        speed = np.convolve(filtered, [0.25, 0.5, 0.25], mode="same")
        accel = np.gradient(filtered, dt)
    else:  # EMPS' published recipe: central differences of the filtered position, twice
        speed = np.gradient(filtfilt(b, a, data.position), dt)
        accel = np.gradient(speed, dt)
    trim = _edge(fs, cutoff, band.decim)
    return Prepared(data, Band(cutoff, band.decim, band.order), speed, accel, trim, b, a)


def _edge(fs: float, cutoff: float, decim: int) -> int:
    """Two corner periods, rounded up to whole decimation blocks: the samples dropped at each end
    (the filters' edge transients), and so how far a sample's influence reaches into the rows."""
    return int(np.ceil(2 * fs / cutoff / decim) * decim) + decim


# Above this share of the fit's rows within the filters' reach of a gap-filled sample, most of
# what the doctor would fit is the export's interpolation, not the drive: refused, not judged.
FILLED_REACH_MAX = 0.5


def check_filled(data: Dataset, band: Band) -> str | None:
    """A warning for a recording with gap-filled rows (`gap` = 1), None without any; DataFileError
    (exit 2) when most rows the fit sees lie within the filters' reach of filled samples. The
    filling is linear: ω̇ constant under a changing u, a misfit the doctor would name as a cause,
    and its false-alarm rate is calibrated on measured rows only."""
    if data.filled is None or not data.filled.any():
        return None
    filled = data.filled.astype(bool)
    n, n_filled = len(filled), int(filled.sum())
    gaps = int(np.count_nonzero(np.diff(filled.astype(np.int8)) == 1) + filled[0])
    reach = _edge(data.sample_rate_hz, min(band.cutoff_hz, 0.4 * data.sample_rate_hz), band.decim)
    seen = np.convolve(filled.astype(float), np.ones(2 * reach + 1), mode="same") > 0.5
    seen_share = float(seen.mean())
    what = (
        f"{data.name}: {n_filled} of {n} rows ({100 * n_filled / n:.3g} %) were filled by "
        f"interpolation across {gaps} gap(s) (gap = 1), and {100 * seen_share:.3g} % of the rows "
        f"lie within the filters' reach ({reach} samples) of one"
    )
    if seen_share > FILLED_REACH_MAX:
        raise DataFileError(
            f"{what}: most of what the fit would see is invented, not measured, so no verdict; "
            "export a stretch without gaps (tvsctl export --start/--end) or record under tvsd --realtime"
        )
    return (
        f"{what}: the fit takes them as measured, so a cause named may come from the filling "
        "(the false-alarm rate holds for measured rows only)"
    )
