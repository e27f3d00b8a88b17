"""The regression the decision rule works on: the baseline's columns and each cause's extra block.

Rows are the band-limited, decimated samples of tvsd.analysis.prep. The left side is the measured
acceleration, and every coefficient is free — input gain, damping (viscous + back-EMF), Coulomb
and Stribeck friction — so the baseline holds for a motor the config does not describe (another
bench's R, kM, J):

    ω̇ = a₀·u(t) + a₁·u(t+1/fs) − c·ω − f·sgn ω − s·e^{−(ω/v₀)²}·sgn ω [+ b] [+ extension] + e

Two input columns (the command now and one sample later) absorb the sampling convention of u
(held from the sample or averaged up to it) and the drive's L/R lag, so a delay must exceed one
sample to be a cause. v₀ is scanned once for the baseline (it is part of the null model).
Rows where the shaft is stuck (|ω| below a small share of the range) are left out: there the
rigid equation with sgn ω friction does not hold, and a dead zone would explain the sticking.

Each cause adds a block of columns, optionally for every value of a scanned parameter (a dead-zone
width, a delay, an order, a drift's parameter). With a free coefficient every extension nests
the baseline, so each is tested by the same likelihood ratio (tvsd.analysis.calibrate).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tvsd.analysis.prep import Prepared
from tvsd.analysis.rules import DEFAULT, Rules

if TYPE_CHECKING:
    from tvsd.analysis.level_nuisance import Levels

MAX_COGGING_ORDER = 24
MAX_DELAY_S = 0.03
N_THRESHOLDS = 24
SUPPORT = 0.01  # a threshold needs 1 % of the samples on each side of it
STUCK_SHARE = 0.02  # |ω| below 2 % of its range: the shaft is (nearly) stuck
V0_GRID = (0.5, 1.0, 2.0, 4.0, 8.0)  # Stribeck speeds tried for the baseline, rad/s (or m/s × 0.01)


@dataclass(frozen=True)
class Option:
    """One value of a cause's scanned parameter: its columns and what it means."""

    effect: dict[str, float | str]
    block: np.ndarray  # rows × k
    names: tuple[str, ...]
    sign: tuple[int, ...] = ()  # required sign of each coefficient (0: any), for physical sense


@dataclass
class Design:
    prep: Prepared
    y: np.ndarray  # acceleration rows
    X: np.ndarray  # baseline columns
    names: tuple[str, ...]
    rows_mask: np.ndarray  # rows used (moving)
    v0: float
    u_top: float  # largest |command|
    options: dict[str, list[Option]] = field(default_factory=dict)
    back_emf: bool = True
    rules: Rules = DEFAULT  # the doctor's switchable rules (tvsd.analysis.rules)
    # the command's held levels whose per-level constant error is a random effect of the null
    # (tvsd.analysis.level_nuisance, read by tvsd.analysis.calibrate); None: none
    levels: Levels | None = None


def _shift(u: np.ndarray, samples: int) -> np.ndarray:
    """u delayed by `samples` (negative: advanced), edges held."""
    if samples == 0:
        return u
    out = np.empty_like(u)
    if samples > 0:
        out[samples:] = u[:-samples]
        out[:samples] = u[0]
    else:
        out[:samples] = u[-samples:]
        out[samples:] = u[-1]
    return out


def build(
    prep: Prepared,
    offset: bool,
    rotary: bool,
    fit_mask: np.ndarray | None = None,
    rules: Rules = DEFAULT,
    with_options: bool = True,
) -> Design:
    """The baseline and every cause's options on the prepared rows; `rules` travel with the design
    to every check that reads one (tvsd.analysis.rules). `with_options=False`: the baseline only."""
    d = prep.data
    rows, band = prep.rows, prep.band_rows
    y = rows(prep.accel)
    w_full = prep.speed
    w = rows(w_full)
    sgn_full = np.sign(w_full)
    u = d.u
    top_w = float(np.max(np.abs(w))) if len(w) else 0.0
    moving = np.abs(w) > STUCK_SHARE * top_w
    if fit_mask is not None:
        moving &= fit_mask
    cols = [band(u), band(_shift(u, -1)), w, band(sgn_full)]
    names = ["a0", "a1", "c", "f"]
    if offset:
        cols.append(np.ones_like(w))
        names.append("b")
    X0 = np.column_stack(cols)
    # Stribeck speed: the v₀ whose column leaves the least (scanned once, part of the null).
    scale = top_w if not rotary else 1.0
    best: tuple[float, float, np.ndarray] | None = None
    for v0 in V0_GRID:
        v = v0 * (scale / 100.0 if not rotary else 1.0)
        col = band(np.exp(-((w_full / v) ** 2)) * sgn_full)
        X = np.column_stack([X0, col])[moving]
        theta, *_ = np.linalg.lstsq(X, y[moving], rcond=None)
        rss = float(np.sum((y[moving] - X @ theta) ** 2))
        if best is None or rss < best[0]:
            best = (rss, v, col)
    assert best is not None
    X = np.column_stack([X0, best[2]])
    names.append("s")
    design = Design(prep, y, X, tuple(names), moving, best[1], float(np.max(np.abs(u))), rules=rules)
    if with_options:
        design.options = _options(prep, rotary, offset)
    return design


def _options(prep: Prepared, rotary: bool, offset: bool = False) -> dict[str, list[Option]]:
    d = prep.data
    rows, band = prep.rows, prep.band_rows
    u = d.u
    w_full = prep.speed
    w = rows(w_full)
    t_frac = (d.t - d.t[0]) / max(float(d.t[-1] - d.t[0]), 1e-9)
    top = float(np.max(np.abs(u)))
    opts: dict[str, list[Option]] = {}
    if rotary:
        phi = d.position
        opts["imbalance"] = [
            Option({"order": 1}, np.column_stack([band(np.sin(phi)), band(np.cos(phi))]), ("s1", "c1"))
        ]
        opts["cogging"] = [
            Option(
                {"order": n},
                np.column_stack([band(np.sin(n * phi)), band(np.cos(n * phi))]),
                ("sN", "cN"),
            )
            for n in range(2, MAX_COGGING_ORDER + 1)
        ]
    if top > 0:
        # A threshold is told from friction and gain only by data on both sides of it: each
        # value needs SUPPORT of the moving samples below and above (else it is not a candidate).
        def supported(x: float) -> bool:
            return supported_threshold(prep, x)

        # Dead zone: applied = u − clip(u, ±u0); the block's coefficient is −a (negative).
        opts["deadzone"] = [
            Option({"u0": x}, band(np.clip(u, -x, x))[:, None], ("dz",), (-1,))
            for x in np.linspace(0.02, 0.5, N_THRESHOLDS) * top
            if supported(x)
        ]
        # Saturation: applied = u − (|u| − U)₊·sgn u; coefficient −a.
        opts["saturation"] = [
            Option(
                {"u_max": x},
                band(np.sign(u) * np.maximum(np.abs(u) - x, 0.0))[:, None],
                ("sat",),
                (-1,),
            )
            for x in np.linspace(0.3, 0.97, N_THRESHOLDS) * top
            if supported(x)
        ]
        dt = 1.0 / d.sample_rate_hz
        n_max = max(2, round(MAX_DELAY_S / dt))
        # Delay: applied = u(t − τ); the block u(t−τ) − u(t) carries +a.
        opts["delay"] = [
            Option({"delay_s": k * dt}, band(_shift(u, k) - u)[:, None], ("dl",), (1,))
            for k in range(2, n_max + 1)
        ]
    neg = w_full < 0
    # With an offset in the baseline, a Coulomb level by direction is that offset (1[ω<0] =
    # (1 − sgn ω)/2): only the viscous slope can differ by direction.
    asym = [w * rows(neg.astype(float))]
    if not offset:
        asym.append(band(-neg.astype(float)))
    opts["friction_asymmetry"] = [Option({}, np.column_stack(asym), ("cn", "fn")[: len(asym)])]
    tf = t_frac
    opts["drift"] = [
        Option({"parameter": "R"}, band(tf * u)[:, None], ("dR",)),
        Option({"parameter": "kv"}, rows(tf * w_full)[:, None], ("dkv",)),
        Option({"parameter": "friction"}, band(tf * np.sign(w_full))[:, None], ("dfr",)),
    ]
    return opts


def options(prep: Prepared, rotary: bool, offset: bool = False) -> dict[str, list[Option]]:
    """Every cause's blocks on `prep` (tvsd.analysis.selection rebuilds the command's blocks on
    a command a named map transformed)."""
    return _options(prep, rotary, offset)


def resonance_columns(prep: Prepared, freq: float) -> np.ndarray:
    t = prep.data.t
    return np.column_stack(
        [prep.band_rows(np.sin(2 * math.pi * freq * t)), prep.band_rows(np.cos(2 * math.pi * freq * t))]
    )


Transform = Callable[[np.ndarray], np.ndarray]


def with_input(design: Design, u_applied: np.ndarray) -> np.ndarray:
    """The baseline's columns with the drive fed `u_applied` (a dead zone, a clip, a delay)."""
    X = design.X.copy()
    X[:, 0] = design.prep.band_rows(u_applied)
    X[:, 1] = design.prep.band_rows(_shift(u_applied, -1))
    return X


def shifted(u: np.ndarray, samples: int) -> np.ndarray:
    return _shift(u, samples)


INPUT_CAUSES = ("deadzone", "saturation", "delay")


def supported_threshold(prep: Prepared, x: float) -> bool:
    """Whether SUPPORT of the samples lie on each side of the command level x (all samples: below
    a dead zone the shaft stands still, and that is the evidence).

    Both sides strictly: a staircase holds its levels exactly, so a level x = the top level had
    ≥ 1 % of samples "not below" it while none exceeded it — a saturation there clips nothing,
    and the refit landed on it (then `sense` called it "above almost every command")."""
    mag = np.abs(prep.data.u)
    if not len(mag):
        return False
    return float(np.mean(mag < x)) >= SUPPORT and float(np.mean(mag > x)) >= SUPPORT
