"""The misfit absorber: friction of any smooth symmetric shape in the doctor's null model.

The baseline's friction is viscous + Coulomb + one Stribeck bump (tvsd.analysis.design), and a
real drive's is not exactly that: LuGre's pre-sliding and a Stribeck speed below the rows kept,
another bench's bearings. What the three terms miss is left in the residual as a function of ω,
and its projection on a cause's columns — a dead zone's near-zero commands, the direction split
of friction asymmetry (on a record whose speeds are not symmetric an odd misfit is not
orthogonal to the even columns), sin φ on a slow multisine — was named as that cause with the
out-of-sample check confirming it (it is systematic; docs/measurements/doctor-false-alarms.md, "False
alarms").

So the null model carries a few more odd basis functions of ω: sgn ω·e^{−|ω|/(c·ω_top)} for
c in SCALES (Stribeck-like decays from the stuck threshold to a third of the top speed).
They are baseline columns: the bootstrap's residual degrees of freedom and the out-of-sample
check count them, and every cause is tested against a model that already has them.

Odd only, by design: an even function of ω is friction that differs by direction, the cause
`friction_asymmetry` itself (with ω and sgn ω in the baseline, |ω| and a constant span exactly
its block), so absorbing it would remove the cause, not the misfit. Nor does an odd function of
ω span a dead zone (a function of the command), a saturation or a delay.
"""

from __future__ import annotations

import numpy as np

from tvsd.analysis.design import Design

SCALES = (0.03, 0.1, 0.3)  # decay speeds, shares of the largest |ω| of the rows
PREFIX = "fo"  # the absorber's column names: fo0.03, ...


def columns(design: Design) -> tuple[np.ndarray, tuple[str, ...]]:
    """The absorber's columns on the design's rows (band-limited as every other column)."""
    prep = design.prep
    w = prep.speed
    top = float(np.max(np.abs(prep.rows(w))))
    if top <= 0:
        return np.zeros((len(design.y), 0)), ()
    s = np.sign(w)
    cols = [prep.band_rows(s * np.exp(-np.abs(w) / (c * top))) for c in SCALES]
    return np.column_stack(cols), tuple(f"{PREFIX}{c:g}" for c in SCALES)


def base_count(design: Design) -> int:
    """The number of the design's baseline columns before the absorber's (which come last)."""
    n = len(design.names)
    while n and design.names[n - 1].startswith(PREFIX):
        n -= 1
    return n


def rigid(design: Design, X: np.ndarray) -> tuple[np.ndarray, int]:
    """X (the design's baseline, then any extension's columns) without the absorber's columns,
    and the baseline's remaining width. The drive's parameters and the causes' sizes are read
    from the rigid model: the absorber's odd shapes trade with viscous and Coulomb friction
    (EMPS's damping read 173 for the published 203.5 N·s/m, its direction ratio 1.62 for 1.44)
    and stand in for misfit, not for the drive."""
    b, k = base_count(design), design.X.shape[1]
    return np.column_stack([X[:, :b], X[:, k:]]), b


def absorb(design: Design) -> Design:
    """The design with the absorber's columns appended to its baseline (in place, returned)."""
    W, names = columns(design)
    if W.shape[1]:
        design.X = np.column_stack([design.X, W])
        design.names = (*design.names, *names)
    return design
