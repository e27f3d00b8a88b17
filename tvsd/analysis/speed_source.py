"""Which speed the doctor differentiates when a recording has both a speed column and an encoder.

A tachometer behind an anti-alias filter carries white (and 1/f) noise of its own: differenced
into an acceleration it grows ∝ f, so 1 rad/s of white noise (1 % of a 100 rad/s full scale) at
1 kHz is 14 rad/s²/√Hz at 50 Hz, where a drive's own vibration is 0.05–1 rad/s^1.5. The encoder's
angle on the same file is known to within a count: its backward difference (the count
difference, the speed of most benches) has a quantisation noise that falls ∝ f below the sample
rate. On the outsider bench (docs/measurements/outsidereff.md) a 20× friction asymmetry read
z 3.3 through the tach and 323 through the encoder, a 10 ms delay 1.45 and 167.

So when φ is measured in open loop the baseline's equation error is compared on both: the
encoder's count difference replaces the recorded speed only when it leaves less than 1/MARGIN of
its residual power (the same rows, band and columns), a difference no sampling of a null reaches
by chance (the rows are thousands). The count step must be known (declared counts, or read from
φ's own grid), so the speed is snapped to it and carries the quantisation floor that every count
difference gets (tvsd.analysis.quantisation); without a grid nothing changes. A speed that is
already a count difference and a closed loop keep theirs. A voltage or duty command held on
levels is read through the encoder too, with its bridge's per-level error carried by the null
(tvsd.analysis.level_nuisance: through a quiet speed it was named on 3 of 14 such nulls without).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from tvsd.analysis import count_grid, level_nuisance
from tvsd.analysis import design as D
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.prep import Band, prepare

# The encoder must leave less than half the recorded speed's residual power: a factor the
# residual's sampling cannot fake (≥ 2000 rows: its relative s.e. is ≤ 3 %), and a bench whose two
# sensors are alike keeps the speed it recorded.
MARGIN = 2.0
# Dataset.meta: why the speed was replaced (the verdict's warning code). Not `omega_source`: that is
# a recording's own optional header key (a daemon export's ω, README), which the doctor read as its
# own note — every export got an `omega_from_encoder` warning. A file's own line of this key is
# dropped by `choose`, so its presence means the doctor replaced the speed.
KEY = "omega_from_encoder"
# The printed angle must sit within this share of a count of the grid (7 significant digits of
# a few hundred radians: 1e-4 rad, 0.13 of an 8192-count step), so rounding recovers each count.
SNAP_TOL = 0.25


def counts_step(data: Dataset) -> float | None:
    """The angle's count q (rad) when φ lies on a grid: the declared counts per revolution, else
    the grid read from φ's own differences; None when neither holds."""
    counts = data.meta.get("encoder_counts_per_rev")
    q = 2 * math.pi / float(counts) if counts is not None else _read_count(data.position)
    if q is None:
        return None
    x = data.position / q
    return q if float(np.max(np.abs(x - np.round(x)))) < SNAP_TOL else None


def _read_count(position: np.ndarray) -> float | None:
    """An undeclared encoder's count from its angle's steps: the printed angle's own rounding
    (7 digits) keeps φ's differences off an exact grid (count_grid.read_step's 1e-3 of a step),
    so the step is the typical smallest difference, refined as the least-squares fit of every
    difference to its whole number of counts, then rounded to whole counts per revolution;
    `counts_step`'s snap of φ itself confirms it (a continuous angle fails it)."""
    d = np.abs(np.diff(position))
    d = d[d > 1e-9 * max(float(np.max(np.abs(position))), 1e-12)]
    if len(d) < 100:
        return None
    q = float(np.median(d[d < 1.5 * np.min(d)]))
    for most in (2, 8):  # one and two counts first, then the few-count steps on the refined q
        k = np.round(d / q)
        near = (k >= 1) & (k <= most)
        if not np.any(near):
            return None
        q = float(d[near] @ k[near] / (k[near] @ k[near]))
    # A rotary encoder has a whole number of counts per revolution: that, not the fit (off by
    # ~1e-5, two counts at 10⁵ counts of travel), is the step the snap is checked on.
    counts = round(2 * math.pi / q)
    return 2 * math.pi / counts if counts >= 1 else None


def encoder_speed(data: Dataset, q: float) -> Dataset:
    """The dataset with its speed the count difference of the snapped angle (row 0 keeps ω)."""
    assert data.speed is not None
    phi = np.round(data.position / q) * q
    speed = np.concatenate([data.speed[:1], np.diff(phi) * data.sample_rate_hz])
    meta = {k: v for k, v in data.meta.items() if k not in (count_grid.STEP_KEY, "omega_timing")}
    meta[count_grid.STEP_KEY] = repr(q * data.sample_rate_hz)
    return replace(data, speed=speed, meta=meta)


def residual_power(data: Dataset, band: Band, mask: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """(mean squared baseline equation error on the moving rows, those rows)."""
    prep = prepare(data, band)
    des = D.build(prep, data.offset_term, data.units.axis == "rotary", with_options=False)
    rows = des.rows_mask if mask is None else des.rows_mask & mask
    theta, *_ = np.linalg.lstsq(des.X[rows], des.y[rows], rcond=None)
    e = des.y[rows] - des.X[rows] @ theta
    return float(np.mean(e**2)), rows


def compared(data: Dataset, band: Band) -> tuple[Dataset, float] | None:
    """(the count-difference dataset, its equation error over the recorded speed's on the rows
    both move in), or None when there is no encoder grid to compare with."""
    if data.speed is None or not data.position_measured or data.units.axis != "rotary":
        return None
    if data.closed_loop:
        # Closed loop: its rules (closed_checks, the instrumented fit) are calibrated on the speed
        # the controller fed back; through the encoder a 20× clip read `drift` (outsidereff.md).
        return None
    if not level_nuisance.fits(data, len(data.u) // band.decim):
        # A voltage (or duty) held on levels goes through a bridge that applies each level with
        # its own constant error (PWM resolution): through a quiet speed it was named on 3 of 14
        # such nulls unless the null carries it (level_nuisance), which costs a dense block.
        return None
    counted = count_grid.recorded_step(data.speed, data.sample_rate_hz, data.meta)
    if count_grid.STEP_KEY in data.meta or counted is not None:
        return None  # already a count difference (dataset.load read its step before re-timing it)
    q = counts_step(data)
    if q is None:
        return None
    alt = encoder_speed(data, q)
    assert alt.speed is not None
    _, moving = residual_power(data, band)
    _, moving_alt = residual_power(alt, band)
    both = moving & moving_alt
    if np.count_nonzero(both) < 100:
        return None
    rec, _ = residual_power(data, band, both)
    enc, _ = residual_power(alt, band, both)
    return alt, enc / rec


def choose(data: Dataset, band: Band) -> Dataset:
    """`data` with the speed that leaves the smaller equation error (see the module's note)."""
    if KEY in data.meta:  # a file's own line of the doctor's key: not the doctor's note
        data = replace(data, meta={k: v for k, v in data.meta.items() if k != KEY})
    found = compared(data, band)
    if found is None or not found[1] * MARGIN < 1.0:
        return data
    alt, ratio = found
    q = float(alt.meta[count_grid.STEP_KEY]) / alt.sample_rate_hz
    alt.meta[KEY] = (
        f"the encoder's count difference (φ on a {2 * math.pi / q:.0f}-count grid) leaves "
        f"{ratio:.2g} of the recorded speed's equation error: used in its place"
    )
    return alt


def same_source(other: Dataset, chosen: Dataset) -> Dataset:
    """A held-out file judged through the speed `chosen` was fitted on: its count difference
    on the same grid (unchanged when its angle is not on it)."""
    step = chosen.meta.get(count_grid.STEP_KEY)
    if KEY not in chosen.meta or step is None or other.speed is None or not other.position_measured:
        return other
    q = float(step) / chosen.sample_rate_hz
    x = other.position / q
    if float(np.max(np.abs(x - np.round(x)))) >= SNAP_TOL:
        return other
    return encoder_speed(other, q)
