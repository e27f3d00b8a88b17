"""Did the shaft move clear of its own speed noise? A stuck drive is no excitation (exit 2).

A recording whose measured speed is noise alone holds nothing about J, the friction or any
cause: its fit named `model_mismatch` ("wrong sign or unit of u"), a cause built on noise. The
check counts the regression rows whose speed stands clear of the noise and refuses the file
(DataFileError, exit 2) when they are too few for the baseline's columns. The noise level comes
from the data alone: the raw speed's second differences (a robust spread), carried through the
band filter and decimation the rows go through. How the noise enters the raw speed sets that
path's gain: a speed measured with white noise (a tachometer, tvsd's own speed) passes the band's
share of it; an encoder's count difference or a position-only file's derivative is a white angle
error differenced, whose noise lies mostly above the band (f² at low frequency). Read as white,
it put a 1024-count encoder's 5 rad/s at 0.7 of the threshold, and 39 of 400 moving encoder
nulls (tests/quantisation_nulls.py) were refused. A count difference's noise has a floor: the
angle is known to within a count, so its error is at least a uniform one's (quantisation_floor);
without it a stuck encoder that flickers a count now and then had a MAD of 0 and passed. The
floor also refuses a shaft turning steadily at ≤ 0.2 counts per sample (its rows stay under
5 σ of it), so the refusal names both: noise or quantisation, stuck or too slow.

A speed sensor of its own (a tachometer) can carry a constant offset, its zero error: a stuck
shaft then reads |ω| ≈ offset ≫ its noise in every row and passed. When the file also measures
the angle φ, a shaft that moves moves its angle too, so the same test runs a second time on φ's
count difference (backward, as an encoder's; its own noise and count floor): too few rows
moving there is no excitation as well, and the line says that the speed and the angle disagree.
A closed-loop scan at a constant speed turns φ steadily: every row moves in both.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tvsd.analysis.count_grid import STEP_KEY
from tvsd.analysis.prep import Prepared, prepare
from tvsd.analysis.quantisation import count_step
from tvsd.errors import DataFileError

MAD_TO_SIGMA = 1.4826  # a normal sample's standard deviation over its median absolute deviation
# A row is moving when |ω| > CLEAR·σ of the rows' noise: a still shaft's row passes with
# probability 2·Φ(−5) = 5.7e-7, so noise alone gives no moving row in any file up to hours long.
CLEAR = 5.0
ROWS_PER_COLUMN = 10  # moving rows per baseline column, the rule doctor.py applies to the fit
ANGLE_KEY = "speed_from_angle"  # Dataset.meta of angle_speed's copy: its speed is φ's difference


def raw_speed(prep: Prepared) -> np.ndarray:
    d = prep.data
    return d.speed if d.speed is not None else np.gradient(d.position, 1.0 / d.sample_rate_hz)


def noise_taps(prep: Prepared) -> np.ndarray:
    """How a white noise source enters the raw speed: the speed's own ([1]), an angle error
    differenced backward (an encoder's count difference, [1, −1]·fs) or centrally (np.gradient of
    a position-only file, [½, 0, −½]·fs); fs is carried by the source's σ (speed units)."""
    d = prep.data
    if d.speed is None:
        return np.array([0.5, 0.0, -0.5])
    differenced = count_step(prep) is not None or ANGLE_KEY in d.meta
    return np.array([1.0, -1.0]) if differenced else np.array([1.0])


def speed_noise(prep: Prepared) -> float:
    """σ of the white source of the raw speed's noise (noise_taps), in speed units. Its second
    differences have variance σ²·‖Δ²∗taps‖² (6σ² for a white speed); the drive's own speed,
    band-limited by its inertia, hardly adds to them, and the median keeps a step's few large
    differences out."""
    d2 = np.diff(raw_speed(prep), 2)
    if len(d2) == 0:
        return 0.0
    norm = float(np.linalg.norm(np.convolve([1.0, -2.0, 1.0], noise_taps(prep))))
    mad = MAD_TO_SIGMA * float(np.median(np.abs(d2 - np.median(d2)))) / norm
    return max(mad, quantisation_floor(prep))


def quantisation_floor(prep: Prepared) -> float:
    """The least σ of a count difference's source (noise_taps [1, −1]), in speed units; 0 for any
    other speed. The angle is known only to within a count, so its error cannot be less than a
    uniform one over a count: σ = q/√12 in angle, step/√12 (step = q·fs) in the source's speed
    units. Without it a stuck encoder that flickers a count now and then has a MAD of exactly 0
    (most of its second differences are 0): σ̂ = 0 and every row with any speed would be moving."""
    step = count_step(prep)
    return 0.0 if step is None else step / np.sqrt(12.0)


def noise_gain(prep: Prepared) -> float:
    """The rows' speed noise per unit of the white source: √Σh² of the path its noise takes
    (noise_taps, prep.lowpass, then prep.rows), summed over the decimation's phases so no tap is
    skipped."""
    taps = noise_taps(prep)
    n = 2 * prep.trim + 8192
    total = 0.0
    for phase in range(max(prep.band.decim, 1)):
        x = np.zeros(n)
        x[n // 2 + phase : n // 2 + phase + len(taps)] = taps
        total += float(np.sum(prep.rows(prep.lowpass(x)) ** 2))
    return float(np.sqrt(total))


def row_noise(prep: Prepared) -> float:
    """σ of the regression rows' speed when the shaft stands still."""
    return speed_noise(prep) * noise_gain(prep)


def moving_rows(prep: Prepared) -> tuple[int, int, float]:
    """(rows whose speed stands clear of CLEAR·σ, rows, σ of the rows' noise)."""
    w = np.abs(prep.rows(prep.speed))
    sigma = row_noise(prep)
    return int(np.count_nonzero(w > CLEAR * sigma)), len(w), sigma


def angle_speed(prep: Prepared) -> Prepared | None:
    """The recording with φ's backward difference as its speed (an encoder's count difference), or
    None when the file has no angle of its own (φ integrated from ω) or no separate speed."""
    d = prep.data
    if d.speed is None or not d.position_measured or len(d.position) < 2:
        return None
    diff = np.diff(d.position) * d.sample_rate_hz
    meta = {k: v for k, v in d.meta.items() if k != STEP_KEY}  # that step was the speed column's
    meta[ANGLE_KEY] = "1"
    return prepare(dataclasses.replace(d, speed=np.concatenate([diff[:1], diff]), meta=meta), prep.band)


def check_moving(prep: Prepared, columns: int) -> None:
    """DataFileError (exit 2) when fewer than ROWS_PER_COLUMN·columns rows move clear of the noise,
    in the speed or, when the file measures it too, in the angle."""
    d = prep.data
    moving, rows, sigma = moving_rows(prep)
    need = ROWS_PER_COLUMN * columns
    if moving >= need:
        angle = angle_speed(prep)
        turned, _, angle_sigma = moving_rows(angle) if angle is not None else (need, rows, 0.0)
        if turned < need:
            raise DataFileError(
                f"{d.path or d.name}: no excitation: the speed column stands clear of its noise in "
                f"{moving} of {rows} regression rows, but the angle phi moves clear of its noise or "
                f"count step ({CLEAR:g} × {angle_sigma:.3g} {d.units.speed}) in only {turned} (at least "
                f"{need} needed): the shaft stood still and the speed sensor reads an offset (a "
                "tachometer's zero error), or phi is not this shaft's angle; record the drive moving, "
                "or check the speed and phi columns"
            )
    if moving < need:
        # The count floor sets σ for a stuck encoder and for one turning under ~0.2 counts per
        # sample alike: the message must hold for both.
        source = "its noise or its encoder's quantisation" if count_step(prep) is not None else "its noise"
        raise DataFileError(
            f"{d.path or d.name}: no excitation: the shaft's speed stands clear of {source} "
            f"({CLEAR:g} × {sigma:.3g} {d.units.speed}, from the data) in only {moving} of its {rows} "
            f"regression rows (at least {need} needed): the drive did not break away or turns too "
            "slowly to be seen; excite it harder or longer"
        )
