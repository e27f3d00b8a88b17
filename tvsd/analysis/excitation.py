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
the angle φ, a shaft that moves moves its angle too: over 20 stretches of the record the range
of the speed's integral is compared with φ's, and where the speed says the shaft turned farther
than the angle's noise (or its count) reaches, φ must have too, in at least half of them. The
stretches are long (a twentieth of the record) so that a slow shaft with a coarse encoder climbs
many counts in each; a closed-loop scan at a constant speed turns φ in every one.

When the doctor reads the speed through the encoder's count difference in place of the recorded
one (tvsd.analysis.speed_source: it leaves less equation error), the motion must also stand clear
of the recorded speed's own noise (`check_recorded`). The swap sharpens the fit of a drive that
moved; it is no evidence that the command moved it. A shaft held under its breakaway creeps in
slips the disturbance gives it: an 8192-count encoder reads them (a few counts now and then, 0.2
counts per sample on average), the tachometer beside it none (outsider null o15230: a duty PRBS
whose four levels all stay under the static friction; through the encoder pre-sliding friction
near zero speed fitted a dead zone's columns, z 32). Every other file the swap reads through the
encoder (146 of seeds 12–17 and the level-held families) has its recorded speed clear of its
noise in ≥ 15× the rows needed (docs/measurements/closedprop.md).
"""

from __future__ import annotations

import itertools

import numpy as np

from tvsd.analysis.count_grid import read_step
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.prep import Prepared
from tvsd.analysis.quantisation import count_step
from tvsd.errors import DataFileError

MAD_TO_SIGMA = 1.4826  # a normal sample's standard deviation over its median absolute deviation
# A row is moving when |ω| > CLEAR·σ of the rows' noise: a still shaft's row passes with
# probability 2·Φ(−5) = 5.7e-7, so noise alone gives no moving row in any file up to hours long.
CLEAR = 5.0
ROWS_PER_COLUMN = 10  # moving rows per baseline column, the rule doctor.py applies to the fit
# The angle is compared with the speed's integral over this many stretches of the record, and
# refused when it agrees in fewer than half of those where the speed says it turned visibly.
ANGLE_STRETCHES = 20


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
    return np.array([1.0, -1.0]) if count_step(prep) is not None else np.array([1.0])


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


def angle_noise(d: Dataset) -> float:
    """σ of the angle's own error: a robust spread of its second differences (white error: 6σ²),
    never under a count's uniform error q/√12 when φ lies on a count grid (declared or seen)."""
    d2 = np.diff(d.position, 2)
    mad = MAD_TO_SIGMA * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0) if len(d2) else 0.0
    counts = d.meta.get("encoder_counts_per_rev")
    q = 2 * np.pi / float(counts) if counts is not None else read_step(np.diff(d.position))
    return max(mad, 0.0 if q is None else q / np.sqrt(12.0))


def angle_agrees(d: Dataset, speed_sigma: float = 0.0) -> tuple[int, int, float]:
    """(stretches in which the speed says the shaft turned farther than the angle's noise can
    reach, those of them in which the angle did, that reach in the angle's units), over
    ANGLE_STRETCHES stretches of the record. Each compares ranges (max − min) within the stretch,
    of the speed's integral and of φ: net travel would cancel over a whole period of an
    oscillation (a 1 Hz square wave in 1 s stretches), and an offset speed would then disagree
    with a shaft that swings. The reach is the range L white samples of σ span (≈ 2·√(2 ln L)·σ)
    plus CLEAR·σ; long stretches let a slow shaft's angle climb out of a coarse encoder's count.
    The speed's own white noise (σ `speed_sigma`, a tachometer's) integrates to a random walk
    whose range over L samples exceeds 2·CLEAR·σ·√L/fs with probability ≤ 4Φ(−CLEAR) ≈ 1e-6
    (reflection principle): a resting stretch's walk is not a claim that the shaft turned."""
    assert d.speed is not None
    n = len(d.t)
    edges = np.linspace(0, n, ANGLE_STRETCHES + 1).astype(int)
    travelled = np.concatenate([[0.0], np.cumsum(0.5 * (d.speed[1:] + d.speed[:-1]) * np.diff(d.t))])
    length = max(int(np.min(np.diff(edges))), 2)
    reach = (2.0 * np.sqrt(2.0 * np.log(length)) + CLEAR) * angle_noise(d)
    walk = 2.0 * CLEAR * speed_sigma * np.sqrt(length) / d.sample_rate_hz
    claimed = np.array([np.ptp(travelled[i:j]) for i, j in itertools.pairwise(edges)])
    seen = np.array([np.ptp(d.position[i:j]) for i, j in itertools.pairwise(edges)])
    visible = claimed > reach + walk
    return int(visible.sum()), int(np.count_nonzero(visible & (seen > reach))), float(reach)


def check_moving(prep: Prepared, columns: int) -> None:
    """DataFileError (exit 2) when fewer than ROWS_PER_COLUMN·columns rows move clear of the noise,
    in the speed or, when the file measures it too, in the angle."""
    d = prep.data
    moving, rows, sigma = moving_rows(prep)
    need = ROWS_PER_COLUMN * columns
    if moving >= need and d.speed is not None and d.position_measured:
        # a tachometer's white noise integrates to a walk; a count difference's to an angle error
        tach = noise_taps(prep).tolist() == [1.0]
        claimed, agreed, clear = angle_agrees(d, speed_noise(prep) if tach else 0.0)
        if 2 * agreed < claimed:
            raise DataFileError(
                f"{d.path or d.name}: no excitation: the speed column stands clear of its noise in "
                f"{moving} of {rows} regression rows and says the shaft turned in {claimed} of "
                f"{ANGLE_STRETCHES} stretches of the record, but the angle phi moved farther than its "
                f"noise or count reaches ({clear:.3g} {d.units.position}) in only {agreed}: the "
                "shaft stood still and the speed sensor reads an offset (a tachometer's zero error), or "
                "phi is not this shaft's angle (a placeholder? leave the column out and the doctor "
                "integrates omega); record the drive moving"
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


def check_recorded(recorded: Prepared, prep: Prepared, columns: int) -> None:
    """DataFileError (exit 2) when the recorded speed (`recorded`) moves clear of its own noise in
    fewer than ROWS_PER_COLUMN·columns rows though the encoder's count difference (`prep`, the
    speed the doctor would fit through) does: see the module's note."""
    moving, rows, sigma = moving_rows(recorded)
    need = ROWS_PER_COLUMN * columns
    if moving >= need:
        return
    d = recorded.data
    enc, _, _ = moving_rows(prep)
    raise DataFileError(
        f"{d.path or d.name}: no excitation: the recorded speed column stands clear of its noise "
        f"({CLEAR:g} × {sigma:.3g} {d.units.speed}, from the data) in only {moving} of its {rows} "
        f"regression rows (at least {need} needed); the encoder's count difference moves in {enc}, "
        "a shaft that creeps or slips without breaking away (moved by the disturbance, not the "
        "command); excite it harder or longer"
    )
