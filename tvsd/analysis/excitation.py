"""Did the shaft move clear of its own speed noise? A stuck drive is no excitation (exit 2).

A recording whose measured speed is noise alone holds nothing about J, the friction or any
cause: its fit named `model_mismatch` ("wrong sign or unit of u"), a cause built on noise. The
check counts the regression rows whose speed stands clear of the noise and refuses the file
(DataFileError, exit 2) when they are too few for the baseline's columns. The noise level comes
from the data alone: the raw speed's second differences (a robust spread), carried through the
band filter and decimation the rows go through.
"""

from __future__ import annotations

import numpy as np

from tvsd.analysis.prep import Prepared
from tvsd.errors import DataFileError

MAD_TO_SIGMA = 1.4826  # a normal sample's standard deviation over its median absolute deviation
# A row is moving when |ω| > CLEAR·σ of the rows' noise: a still shaft's row passes with
# probability 2·Φ(−5) = 5.7e-7, so noise alone gives no moving row in any file up to hours long.
CLEAR = 5.0
ROWS_PER_COLUMN = 10  # moving rows per baseline column, the rule doctor.py applies to the fit


def raw_speed(prep: Prepared) -> np.ndarray:
    d = prep.data
    return d.speed if d.speed is not None else np.gradient(d.position, 1.0 / d.sample_rate_hz)


def speed_noise(prep: Prepared) -> float:
    """σ of the raw speed's white noise. Δ²x of a white sequence has variance 6σ²; the drive's
    own speed, band-limited by its inertia, hardly adds to it, and the median keeps a step's
    few large differences out."""
    d2 = np.diff(raw_speed(prep), 2)
    if len(d2) == 0:
        return 0.0
    return MAD_TO_SIGMA * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0)


def noise_gain(prep: Prepared) -> float:
    """The rows' speed noise per unit white noise of the raw speed: √Σh² of the path prep takes
    (prep.lowpass, then prep.rows), summed over the decimation's phases so no tap is skipped."""
    n = 2 * prep.trim + 8192
    total = 0.0
    for phase in range(max(prep.band.decim, 1)):
        x = np.zeros(n)
        x[n // 2 + phase] = 1.0
        total += float(np.sum(prep.rows(prep.lowpass(x)) ** 2))
    return float(np.sqrt(total))


def row_noise(prep: Prepared) -> float:
    """σ of the regression rows' speed when the shaft stands still."""
    return speed_noise(prep) * noise_gain(prep)


def check_moving(prep: Prepared, columns: int) -> None:
    """DataFileError (exit 2) when fewer than ROWS_PER_COLUMN·columns rows move clear of the noise."""
    d = prep.data
    w = np.abs(prep.rows(prep.speed))
    sigma = row_noise(prep)
    moving = int(np.count_nonzero(w > CLEAR * sigma))
    need = ROWS_PER_COLUMN * columns
    if moving < need:
        raise DataFileError(
            f"{d.path or d.name}: the shaft's speed stands clear of its noise ({CLEAR:g} × "
            f"{sigma:.3g} {d.units.speed}, from the data) in only {moving} of {len(w)} samples "
            f"(at least {need} needed): no excitation, the drive did not break away; excite it "
            "harder or longer"
        )
