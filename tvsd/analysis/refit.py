"""The command maps' structural refits: a dead zone, clip or delay the decision's linearised block
found is refitted as the map itself (the drive fed the transformed command, the input gain shared),
and judged by whether that refit lands on an effect (`dissolved`), on the sampling convention
(`convention_unpinned`), or beats the recorded command at all (`structural_lr`). tvsd.analysis.verdict
names a command-side cause only through these.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.gls import gls
from tvsd.recording.csvfile import U_SAMPLING

DZ_REFIT_SPAN = 0.6  # dead-zone widths profiled up to this share of the largest command
DZ_REFIT_POINTS = 120
DZ_CHI2_95 = 3.841  # χ²₁ 95 % point: the width's profile-likelihood interval
STRUCTURAL_CHI2 = DZ_CHI2_95  # a command map's refit must beat the recorded command by this (structural_lr)


def refit_input(
    design: D.Design, out: C.Outcome, cause: str, u: np.ndarray
) -> tuple[dict[str, Any], np.ndarray]:
    """Threshold or delay by the structural model: the drive fed the transformed command."""
    if cause == "deadzone":
        return _refit_deadzone(design, out, u)
    top = float(np.max(np.abs(u)))
    fs = design.prep.data.sample_rate_hz
    grid: list[tuple[dict[str, Any], np.ndarray]] = []
    if cause == "saturation":
        for x in np.linspace(0.2, 1.0, 41) * top:
            if D.supported_threshold(design.prep, x):
                grid.append(({"u_max": float(x)}, np.clip(u, -x, x)))
    else:
        for k in range(0, round(D.MAX_DELAY_S * fs) + 1):
            grid.append(({"delay_s": k / fs}, D.shifted(u, k)))
    if not grid:  # no supported value on the fine grid: the scanned one stands
        grid.append(({}, u))
    best: tuple[float, dict[str, Any], np.ndarray, np.ndarray] | None = None
    for effect, ua in grid:
        fit = gls(design.y, D.with_input(design, ua), out.ar, out.keep)
        if best is None or fit.rss < best[0]:
            best = (fit.rss, effect, ua, fit.theta)
    assert best is not None
    effect, theta = dict(best[1]), best[3]
    if cause == "delay" and theta[0] + theta[1] != 0:
        # The input columns u(t−k), u(t−k+1) with weights a₀, a₁ are u delayed by k − a₁/(a₀+a₁)
        # samples (to first order in the band): the delay to a fraction of a sample, where the
        # grid alone is ±1 (tvsd multisine 1.5/3.1/5/11.5 ms → 1.57/3.18/5.08/11.55; bench-dev
        # 3.1/11.5 → 3.11/11.7; the grid gave 3/3/6/13 and 4/11).
        k = round(float(effect["delay_s"]) * fs)
        effect["grid_samples"] = k
        effect["delay_s"] = (k - float(theta[1] / (theta[0] + theta[1]))) / fs
    return effect, best[2]


def dissolved(cause: str, effect: dict[str, Any], u: np.ndarray, fs: float) -> bool:
    """The structural refit lands on "no effect": the scanned block fitted noise or misfit, not
    the cause. A delay on grid cell 0, or under one sample by its fraction (the
    baseline's two input columns already hold it); a saturation that clips less than the
    support a threshold needs (D.SUPPORT of the samples; it used to become `model_mismatch`,
    "above almost every command", on nulls whose best clip was the largest command itself)."""
    if cause == "delay":
        # Grid cell 1 counts when its fraction puts the delay past one sample (1.5 ms read
        # as 1.62 ms from cell 1 was dissolved: 2 of 20 matrix delays at 3x, seed 6).
        return int(effect.get("grid_samples", 0)) < 1 or float(effect["delay_s"]) < 1.0 / fs
    if cause == "saturation" and "u_max" in effect:
        return float(np.mean(np.abs(u) > float(effect["u_max"]))) < D.SUPPORT
    return False


def convention_unpinned(data: Dataset, effect: dict[str, Any]) -> bool:
    """A delay under two samples on a recording that does not say how its command was sampled.

    The delay is measured against tvsd's convention (u and ω both the means over the interval
    up to the sample). A bench that holds each command from its sample on (the outsider
    generator, most drives) applies it one full sample later: on the outsider's nulls that
    alone put the delay at 1.0 sample, and the drive's own sub-sample lags (a larger L/R, an
    inner current loop) took it to 1.09-1.59 samples, past the one-sample edge, named `delay`.
    A hold is a pure delay, the same phase −ωτ as a cause, so no test on the recording can
    separate it: declared (`# u_sampling: hold` shifts u by a sample on load, dataset.py) it is
    removed; undeclared, one sample more is needed before a delay is a cause."""
    if data.meta.get("u_sampling") in U_SAMPLING:
        return False
    return float(effect["delay_s"]) < 2.0 / data.sample_rate_hz


def structural_lr(design: D.Design, out: C.Outcome, u: np.ndarray, u_app: np.ndarray) -> float:
    """The structural refit's likelihood ratio against no effect: the drive fed the transformed
    command (its refitted width, clip or delay) against the drive fed the recorded one, every
    other baseline coefficient refitted in both, in units of the noise variance (χ²₁ under "no
    effect": one parameter, the width, clip level or delay).

    The decision tests a command map by a linearised block with free coefficients; the cause is
    the map itself, one parameter with the drive's own gain. Where the block fits something no
    such map makes, the map fitted at its best value explains nothing — its 95 % profile
    interval reaches "no effect" (the dead zone's u0_interval reaches 0). In closed loop that is
    what the command-side alarms were: the law's answer to the noise makes the command
    correlate with the equation's error, which the bootstrap (conditioning on the regressors)
    does not represent, and the linearised blocks fit it (a dead zone at z 10.1 whose refit
    landed on the grid's first width, 0.03 V, and fitted worse than no dead zone, LR −6.5; a
    clip at z 6.5 whose best supported level fitted worse than no clip, LR −55) — where the
    matrix's closed-loop dead zones, clips and delays gave LR 5.5–1.4e4."""
    none = gls(design.y, D.with_input(design, u), out.ar, out.keep).rss
    fit = gls(design.y, D.with_input(design, u_app), out.ar, out.keep).rss
    var = fit / max(out.n - design.X.shape[1] - 1, 1)
    return (none - fit) / var if var > 0 else 0.0


def dead_zone(u: np.ndarray, u0: float) -> np.ndarray:
    return np.where(np.abs(u) <= u0, 0.0, u - np.sign(u) * u0)


def _refit_deadzone(design: D.Design, out: C.Outcome, u: np.ndarray) -> tuple[dict[str, Any], np.ndarray]:
    """The width by its profile likelihood: the drive fed the dead-zoned command, gain, Coulomb
    and every other baseline coefficient refitted at each width.

    No width is excluded for lack of commands below it (the test's scan needs that support, the
    refit does not): a width below every command level still shows where the command and the
    motion have opposite signs (reversals), where a dead zone and Coulomb friction push opposite
    ways — the only place the two are told apart, so the linearised block's trade with the free
    Coulomb level biased the width up to the smallest supported level (0.71 V read as 1.56 V).
    The profile's minimum is refined by a parabola through its neighbours; the interval is where
    the profile stays within χ²₁(95 %) of it (whitened RSS in units of its variance).
    """
    top = float(np.max(np.abs(u)))
    xs = np.linspace(0.0, DZ_REFIT_SPAN, DZ_REFIT_POINTS + 1)[1:] * top
    rss = np.array([gls(design.y, D.with_input(design, dead_zone(u, x)), out.ar, out.keep).rss for x in xs])
    k = int(np.argmin(rss))
    x_best = float(xs[k])
    if 0 < k < len(xs) - 1:
        r_m, r_0, r_p = rss[k - 1], rss[k], rss[k + 1]
        curv = r_m - 2 * r_0 + r_p
        if curv > 0:
            x_best = float(xs[k] + 0.5 * (r_m - r_p) / curv * (xs[1] - xs[0]))
    n = out.n
    var = float(rss[k]) / max(n - design.X.shape[1] - 1, 1)
    inside = xs[rss - rss[k] <= DZ_CHI2_95 * var]
    effect: dict[str, Any] = {"u0": x_best}
    if len(inside):
        step = float(xs[1] - xs[0])
        effect["u0_interval"] = [max(float(inside.min()) - step, 0.0), float(inside.max()) + step]
    return effect, dead_zone(u, x_best)
