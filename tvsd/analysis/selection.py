"""Forward selection: every cause the data support, ranked, at the decision's own false-alarm rate.

The decision (tvsd.analysis.calibrate, tvsd.analysis.verdict) names the one extension that
explains significantly more than the baseline. A recording can hold more than one: the SIL
daemon's link delays the command by ~6 ms *and* its plant may carry an imbalance, and the
larger of the two hid the other. So once a cause is named, it becomes part of the baseline
(its fitted columns, or for a map of the command the transformed command itself) and the
remaining candidates are tested again by the same rule against that extended model:

- its own whitening (the AR noise model refitted on the extended model's residual),
- its own parametric bootstrap: the null of step k is "the baseline plus the k − 1 causes
  already named, and nothing else", and the gate is the (1 − α) point of that null's maxima,
- the same structural refits, dissolve rule, drift check and out-of-sample confirmation.

Why the false-alarm rate stays α. On a recording where nothing is hidden, a second cause can
only be named after a first one was, so "any cause named on a null" is the first step's event,
probability α, exactly as before. On a recording with true causes, a spurious extra cause needs
the step after the last true one to pass its gate, whose null is then true (the model holds
every real cause): probability α again. Selection stops at the first step where nothing passes,
or at MAX_CAUSES. (The gate's threshold still counts the accepted causes' own statistics in the
maxima it is calibrated on when they cannot be dropped from the scan — a line's resonance scan
is always run — which only makes later steps a little stricter.)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tvsd.analysis import absorber, crossval
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.gls import gls
from tvsd.analysis.linescan import RES_MIN_HZ, line_scan

MAX_CAUSES = 3
NOT_CAUSES = ("none", "model_mismatch")
# Causes whose block is a function of the command: after one of them is named, their blocks are
# rebuilt on the command as the named map applies it (a dead zone of the delayed command).
COMMAND_BLOCKS = (*D.INPUT_CAUSES, "drift")


@dataclass(frozen=True)
class Named:
    """One cause of the ranked list: what its step's test said of it."""

    cause: str
    effect: dict[str, Any]
    z: float  # its statistic, standardised by its own null at its step
    threshold: float  # the gate at its step (z > threshold names it)
    p: float  # bootstrap p-value of this cause alone at its step
    cv_gain: float  # out-of-sample gain over the model before it, in noise variances
    step: int  # 1 = the top cause


def extend(design: D.Design, cause: str, X_fin: np.ndarray, u_applied: np.ndarray) -> D.Design:
    """The design whose baseline holds the named cause, without it among the candidates.

    A block cause's columns go before the misfit absorber's, so absorber.rigid and the
    translation of later causes read them as baseline (a later imbalance's amplitude is then
    measured with the delay in the model). A command map replaces the command itself."""
    k = design.X.shape[1]
    options = {c: o for c, o in design.options.items() if c != cause}
    if cause in D.INPUT_CAUSES:
        data = dataclasses.replace(design.prep.data, u=np.asarray(u_applied, dtype=float))
        prep = dataclasses.replace(design.prep, data=data)
        # rotary=False: the angle's blocks (imbalance, cogging: half the cost) are not rebuilt
        rebuilt = D.options(prep, False, data.offset_term)
        for c in COMMAND_BLOCKS:
            if c in options and c in rebuilt:
                options[c] = rebuilt[c]
        return dataclasses.replace(design, prep=prep, X=np.asarray(X_fin[:, :k]), options=options)
    block = np.asarray(X_fin[:, k:])
    b = absorber.base_count(design)
    X = np.column_stack([design.X[:, :b], block, design.X[:, b:]])
    names = (*design.names[:b], *(f"{cause}{i}" for i in range(block.shape[1])), *design.names[b:])
    return dataclasses.replace(design, X=X, names=names, options=options)


def without(out: C.Outcome, causes: set[str], lines: np.ndarray | None = None) -> C.Outcome:
    """The outcome with causes already named left out of the candidates, and a resonance at a
    line of the reference (`lines`: allowed frequencies of the scan) too."""
    tested = [t for t in out.tested if t.cause not in causes and not _at_reference_line(t, lines)]
    sig = bool(tested and tested[0].z > out.threshold)
    return dataclasses.replace(out, tested=tested, significant=sig)


def reference_scan(design: D.Design) -> np.ndarray | None:
    """Where the line scan may name a mode in a closed-loop recording: not at the reference's own
    lines. The scan (linescan.line_scan) leaves out the command's lines, where a rigid model's
    small misfit of the drive's response leaves a line no torque test tells from a mode; with
    identify's PRBS on the command, the reference multisine's lines sink under it there, and the
    SIL daemon's export named `resonance` at 6.80 Hz, the multisine's 34th harmonic of 0.2 Hz,
    as a third cause. None: no reference column."""
    ref = design.prep.data.speed_reference
    if ref is None:
        return None
    prep = design.prep
    rows = prep.rows(np.asarray(ref, dtype=float))
    fs_rows = 1.0 / float(np.median(np.diff(prep.t_rows)))
    scan = line_scan(np.zeros(len(rows)), [rows], fs_rows, fs_rows / 2)
    return np.asarray(scan.f[scan.scan | (scan.f < RES_MIN_HZ)])


def _at_reference_line(t: C.Tested, allowed: np.ndarray | None) -> bool:
    if allowed is None or t.cause != "resonance" or not len(allowed) or not math.isfinite(t.frequency_hz):
        return False
    step = float(allowed[1] - allowed[0]) if len(allowed) > 1 else 1.0
    return bool(np.min(np.abs(allowed - t.frequency_hz)) > 1.5 * step)


def cv_gain(design: D.Design, out: C.Outcome, verdict: Any) -> float:
    """The named extension's out-of-sample gain (crossval.heldout_gain) over the design's model."""
    if verdict.X.shape[1] == design.X.shape[1] and np.array_equal(verdict.X, design.X):
        return 0.0
    return float(crossval.heldout_gain(design, out, verdict.X))


def further(
    design: D.Design,
    verdict: Any,
    params: dict[str, float],
    err: dict[str, float],
    data: Dataset,
    seed: int,
    cap: int = MAX_CAUSES,
) -> list[Named]:
    """The causes after the top one (`verdict.cause`, already named on `design`), best first.

    Each step runs the whole decision again (tvsd.analysis.verdict.name_cause) on the design
    extended by every cause named so far; a step that names nothing, or whose best extension
    makes no physical sense (model_mismatch), ends the list."""
    from tvsd.analysis.verdict import name_cause

    named: list[Named] = []
    taken = {verdict.cause}
    cur, prev = design, verdict
    lines = reference_scan(design)
    for step in range(2, cap + 1):
        cur = extend(cur, prev.cause, prev.X, prev.u_applied)
        out = without(C.test_all(cur, seed=seed), taken, lines)
        if not out.significant:
            break
        fit = gls(cur.y, cur.X, out.ar, out.keep)
        # The drive's parameters were judged with the top cause in the model (the verdict's
        # physical checks); a later cause is judged by its gate, its own physical sense and its
        # out-of-sample gains, not refused for moving a friction level of a closed-loop fit
        # (delay then imbalance, identify, 10x: imbalance z 256 > 3.6 was `model_mismatch`,
        # "Coulomb friction negative", once the imbalance was in the model).
        v = name_cause(cur, out, fit, params, err, data, drive_identifiable=False)
        if v.cause in NOT_CAUSES or v.cause in taken:
            break
        # The cause as reported (a threshold's or a delay's structural refit, not the linearised
        # block the gate's confirmation used) must predict held-out folds better too: a third
        # cause `saturation` on a friction asymmetry + imbalance multisine passed the gate
        # (z 4.7 > 3.4) and its clip lost 84 noise variances out of sample.
        gain = cv_gain(cur, out, v)
        if not gain > 0:
            break
        top = next(t for t in out.tested if t.cause == v.cause)
        effect = {**v.effect, **amplitude_se(cur, out, v, params["J"], err.get("J", 0.0))}
        named.append(Named(v.cause, effect, top.z, out.threshold, top.p, gain, step))
        taken.add(v.cause)
        prev = v
    return named


def amplitude_se(
    design: D.Design, out: C.Outcome, verdict: Any, J: float, se_J: float = 0.0
) -> dict[str, float]:
    """A periodic torque's amplitude standard error: the delta method on its sin/cos coefficients'
    GLS covariance (the rigid fit its amplitude was translated from), and J's relative error in
    quadrature (amplitude = |J| × the fitted acceleration)."""
    if verdict.cause not in ("imbalance", "cogging", "resonance"):
        return {}
    X_rigid, b = absorber.rigid(design, verdict.X)
    if X_rigid.shape[1] < b + 2:
        return {}
    fit = gls(design.y, X_rigid, out.ar, out.keep)
    cs, cc = float(fit.theta[b]), float(fit.theta[b + 1])
    h = math.hypot(cs, cc)
    if h == 0:
        return {}
    g = np.array([cs, cc]) / h
    rel = math.sqrt(max(float(g @ fit.cov[b : b + 2, b : b + 2] @ g), 0.0)) / h
    rel_J = se_J / abs(J) if J and math.isfinite(se_J) else 0.0
    return {"amplitude_se": abs(J) * h * math.hypot(rel, rel_J)}
