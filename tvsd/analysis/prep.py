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


@dataclass(frozen=True)
class Band:
    cutoff_hz: float = 100.0
    decim: int = 4
    order: int = 4


EMPS_BAND = Band(cutoff_hz=100.0, decim=10)


@cache
def _antialias(q: int) -> tuple[np.ndarray, np.ndarray]:
    b, a = cheby1(8, 0.05, 0.8 / q)
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

    def rows(self, column: np.ndarray) -> np.ndarray:
        """Parallel-decimate one full-rate column into regression rows."""
        if self.band.decim > 1:  # scipy's decimate(ftype="iir", zero_phase=True), its filter designed once
            b, a = _antialias(self.band.decim)
            column = filtfilt(b, a, column)[:: self.band.decim]
        keep = self.trim // self.band.decim
        return column[keep : len(column) - keep]

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
    # Drop two corner periods at each end, rounded up to whole decimation blocks.
    trim = int(np.ceil(2 * fs / cutoff / band.decim) * band.decim) + band.decim
    return Prepared(data, Band(cutoff, band.decim, band.order), speed, accel, trim, b, a)
