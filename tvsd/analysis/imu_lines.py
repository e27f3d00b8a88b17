"""The dominant vibration line of MPU6050 recordings, and how it follows the rotation speed.

Used on the third-party BLDC throttle sweep in ../shared/data/real (SOURCE.md there): raw polled
reads (≈ 890 Hz, non-uniform), so the z acceleration is resampled to the median rate before a
Welch spectrum. If the line is the once-per-revolution imbalance (MODEL-NOTES §4), its frequency
rises in proportion to speed; the test asserts the trend, not a value.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import welch

from tvsd.errors import DataFileError

MIN_LINE_HZ = 20.0  # below: gravity drift, handling, the PSD's low-frequency leakage


@dataclass(frozen=True)
class Line:
    path: Path
    throttle: int
    rate_hz: float
    dominant_hz: float
    rms_g: float


def dominant_line(path: Path) -> Line:
    try:
        a = np.loadtxt(path, delimiter=",")
    except (OSError, ValueError) as exc:
        raise DataFileError(f"{path}: not a 4-column MPU6050 record ({exc})") from exc
    if a.ndim != 2 or a.shape[1] != 4 or len(a) < 256:
        raise DataFileError(f"{path}: expected ≥ 256 rows of 4 columns (ns, ax, ay, az)")
    t = np.cumsum(a[:, 0]) * 1e-9
    rate = 1.0 / float(np.median(np.diff(t)))
    grid = np.arange(t[0], t[-1], 1.0 / rate)
    z = np.interp(grid, t, a[:, 3])
    f, p = welch(z - z.mean(), fs=rate, nperseg=min(len(z), 2048))
    band = f >= MIN_LINE_HZ
    match = re.search(r"_(\d+)\.txt$", path.name)
    throttle = int(match.group(1)) if match else -1
    return Line(path, throttle, rate, float(f[band][np.argmax(p[band])]), float(np.std(z)))


def sweep(folder: Path, min_rms_g: float = 0.02) -> list[Line]:
    """Lines of every record in the folder, by throttle; runs without vibration (a motor that did
    not spin, as SOURCE.md notes for one of the 1200 files) are left out by their RMS."""
    lines = [dominant_line(p) for p in sorted(folder.glob("accel_speed_*.txt"))]
    return sorted((ln for ln in lines if ln.rms_g >= min_rms_g), key=lambda ln: ln.throttle)
