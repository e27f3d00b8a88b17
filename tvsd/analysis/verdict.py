"""From the decision's winner to DESIGN.md's cause and parameters: which candidate is named, and why
each other one is not (WHY).

The decision (tvsd.analysis.calibrate) says which extension explains significantly more than
the baseline; here its free coefficients become the cause's physical parameters (torques = J ×
the fitted acceleration), scanned thresholds and delays are refitted structurally (the command
itself transformed, the input gain shared: tvsd.analysis.refit), a drift must also show in
separate time windows (tvsd.analysis.drift), the winner must predict held-out folds
(tvsd.analysis.crossval), and what is reported must make physical sense (tvsd.analysis.sense).
The held-out speed simulation of the named cause is tvsd.analysis.heldout_sim.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from tvsd.analysis import absorber, asymmetry, crossval, drift, refit, sense
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.closed_checks import NO_POWER, Confirmation
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.gls import GLS, gls
from tvsd.analysis.physical import physical

# Why a candidate is not named: a code for programs, a sentence for people (candidates[i].why_not).
WHY: dict[str, tuple[str, str]] = {
    "below_gate": ("below_gate", "its z is below the gate"),
    "command_side_dissolved": (
        "command_side_dissolved",
        "a command-side cause ranked above it dissolved in its structural refit, so this block "
        "(a function of the same command) fits the same misfit",
    ),
    "refit_no_effect": (
        "refit_no_effect",
        "its structural refit (the drive fed the transformed command) lands on no effect",
    ),
    "sampling_convention": (
        "sampling_convention",
        "its delay {ms:.3g} ms is under two samples and the recording does not declare "
        "'# u_sampling: mean|hold': a command held from its sample acts one sample later than one "
        "averaged over the interval up to it (tvsd's), a pure delay of the same shape, so one "
        "sample of it may be the bench's convention, not a cause",
    ),
    "refit_not_better": (
        "refit_not_better",
        "its structural refit does not beat the recorded command (likelihood ratio {lr:.1f} "
        "<= 3.84, chi2 95 %): the linearised block fitted something no such map makes",
    ),
    "not_instrumented": (
        "not_instrumented",
        "in closed loop it is not confirmed on the instrumented design (the command answers the noise, "
        "so the least-squares block can fit the feedback, not the cause)",
    ),
    "instrument_no_power": (
        "instrument_no_power",
        "in closed loop its confirmation on the instrumented design has no power for it: the effect "
        "least squares found is {power:.1f} of the instrumented estimate's standard errors (< 1.96), "
        "so the instruments cannot resolve a change this size (neither confirmed nor contradicted); "
        "record a longer or more varied reference (steps of several sizes, tvsctl identify)",
    ),
    "drift_windows": (
        "drift_windows",
        "refits on separate time windows do not trend the drift's way",
    ),
    "out_of_sample": (
        "out_of_sample",
        "fitted on four fifths, it does not predict the fifth left out better than the baseline",
    ),
    "ranked_below": (
        "ranked_below",
        "{named} ranked above it and was named; further causes are tested by forward selection",
    ),
}
# Causes besides the command maps whose blocks are functions of the command or the speed (the
# drift of R is u·t; of kv and friction, ω's columns · t; the direction split, ω's): in closed loop
# they are confirmed on the instrumented design too (name_cause's `instrumented`). And the line
# scan's resonance: its block is exogenous, but least squares on a command that answers the noise
# leaves the law's answer in the residual, shaped by the loop (the spectral peak's rule,
# closed_checks.peak_in_plant); a closed-loop outsider null's 21.5 Hz line (o17046, z 4.17, the
# tach's noise fed back) is not in the instrumented fit's residual (docs/measurements/res17.md).
INSTRUMENTED_TOO = ("drift", "friction_asymmetry", "resonance")


@dataclass(frozen=True)
class Scored:
    cause: str
    effect: dict[str, Any]
    z: float  # likelihood ratio standardised by its own bootstrap null
    p: float  # bootstrap p-value of this cause alone
    significant: bool
    heldout_gain_pct: float = math.nan
    why_not: tuple[str, str] | None = None  # (code, sentence) when not named (WHY)


@dataclass
class Verdict:
    ranked: list[Any]
    cause: str
    effect: dict[str, Any]
    reason: str | None
    residual: np.ndarray  # unwhitened rows of the final model's equation error
    X: np.ndarray  # the final model's columns
    theta: np.ndarray
    u_applied: np.ndarray  # the command as the final model's drive sees it


def name_cause(
    design: D.Design,
    out: C.Outcome,
    fit: GLS,
    params: dict[str, float],
    err: dict[str, float],
    data: Dataset,
    drive_identifiable: bool = True,
    friction_judged: bool = True,
    instrumented: Confirmation | None = None,
) -> Verdict:
    """`drive_identifiable` False (closed loop, constant reference): the command answers the
    speed's noise, so J, kv, τc come out biased by the feedback and are not judged.
    `friction_judged` False (closed loop by least squares, a moving reference): the same bias
    holds the damping's and Coulomb level's signs (their standard errors do not hold it: 4 of
    220 identify nulls of matrix seed 52 were `model_mismatch`, "negative Coulomb
    friction", at 3+ standard errors); the input gain and J are still judged.
    `instrumented` (closed loop by least squares): whether a cause whose block is a function of
    the command or the speed (the command maps, INSTRUMENTED_TOO) also passes the decision on
    the instrumented design (closed_checks.instrumented_check); a command map that does not is
    dissolved like a refit that lands on no effect, the others are not named."""
    J = params["J"]
    u = design.prep.data.u  # the recorded command, or in closed loop its instrument (instrument.py)
    ranked: list[Any] = []
    chosen: tuple[str, dict[str, Any], np.ndarray, np.ndarray] | None = None  # cause, effect, X, u
    disowned = False  # a command-side winner dissolved in its structural refit
    for t in out.tested:
        above = out.significant and t.z > out.threshold
        effect: dict[str, Any] = dict(t.option.effect) if t.option is not None else {}
        X_ext, u_app = design.X, u
        if t.cause == "resonance":
            X_ext = np.column_stack([design.X, D.resonance_columns(design.prep, t.frequency_hz)])
            effect = {"frequency_hz": t.frequency_hz}
        elif t.option is not None and t.cause not in D.INPUT_CAUSES:
            X_ext = np.column_stack([design.X, t.option.block])
        dissolved = False
        why: tuple[str, str] | None = None  # (code, sentence): why a candidate above the gate is not named
        if above and chosen is None and t.cause in D.INPUT_CAUSES and disowned:
            # A command-side block ranked higher dissolved in its refit: what it fitted is misfit
            # where the command acts, and the other command-side blocks (functions of the same
            # command) see that same misfit — in closed loop the command answers the noise, and
            # 3 of 6 closed-loop null alarms were a dead zone or a clip named after a dissolved
            # delay at z 8.5–9.7.
            dissolved = True
            why = WHY["command_side_dissolved"]
        elif above and chosen is None and t.option is not None and t.cause in D.INPUT_CAUSES:
            effect, u_app = refit.refit_input(design, out, t.cause, u)
            X_ext = D.with_input(design, u_app)
            if refit.dissolved(t.cause, effect, u, design.prep.data.sample_rate_hz):
                why = WHY["refit_no_effect"]
            elif t.cause == "delay" and refit.convention_unpinned(design.prep.data, effect):
                code, text = WHY["sampling_convention"]
                why = (code, text.format(ms=1e3 * float(effect["delay_s"])))
            elif (lr := refit.structural_lr(design, out, u, u_app)) <= refit.STRUCTURAL_CHI2:
                why = (WHY["refit_not_better"][0], WHY["refit_not_better"][1].format(lr=lr))
            elif instrumented is not None and not instrumented(t.cause):
                why = WHY["not_instrumented"]
            dissolved = disowned = why is not None
        if (above and chosen is None) or t.cause in (
            "imbalance",
            "cogging",
            "resonance",
            "friction_asymmetry",
        ):
            X_rigid, b = absorber.rigid(design, X_ext)
            th = gls(design.y, X_rigid, out.ar, out.keep).theta
            effect.update(_translate(t.cause, effect, th, design, J, b))
        ok = above and not dissolved
        if ok and t.cause == "drift" and t.coef is not None:
            # No instrumented confirmation follows (open loop; a closed loop whose reference is not
            # excited, closed_checks.instrumented_check; the opt-in 2SLS design): the windows'
            # trend is the drift's only evidence beyond the gate, judged at the decision's α
            # (drift.confirmed).
            alone = instrumented is None
            ok = drift.confirmed(design, out, str(effect["parameter"]), float(t.coef[0]), alone)
            why = None if ok else WHY["drift_windows"]
        if ok and chosen is None:
            # Out of sample: fitted on four fifths, the extension must predict the fifth left out
            # better than the baseline (summed over the five) — what misfit of one stretch, or a
            # scan's luck, explains does not carry over.
            # The model checked is the one the decision tested (baseline + the winning block),
            # not the structural refit, which can trade differently with friction.
            X_cv = X_ext if t.option is None else np.column_stack([design.X, t.option.block])
            ok = crossval.heldout_gain(design, out, X_cv) > 0.0
            why = None if ok else WHY["out_of_sample"]
        if ok and chosen is None and instrumented is not None and t.cause in INSTRUMENTED_TOO:
            ok = instrumented(t.cause)  # a function of the command or the speed (closed_checks.py)
            why = None if ok else _unconfirmed(instrumented, t)
            if why is not None and why[0] == "instrument_no_power" and _ls_alone(design, out, t, effect):
                ok, why = True, None
        if not above:
            why = WHY["below_gate"]
        elif ok and chosen is not None:
            why = (WHY["ranked_below"][0], WHY["ranked_below"][1].format(named=chosen[0]))
        ranked.append(Scored(t.cause, effect, t.z, t.p, ok and chosen is None, why_not=why))
        if ok and chosen is None:
            chosen = (t.cause, effect, X_ext, u_app)
    cause, effect_out = "none", dict[str, Any]()
    X_fin, u_fin = design.X, u
    if chosen is not None:
        cause, effect_out, X_fin, u_fin = chosen
        # Judge the drive's parameters with the named cause in the model: an unmodelled strong
        # torque inflates the baseline's uncertainty, not the drive's.
        X_rigid, b = absorber.rigid(design, X_fin)
        fin = gls(design.y, X_rigid, out.ar, out.keep)
        params, err = physical(design, fin.theta[:b], fin.cov[:b, :b], data.b_u, data.b_omega)
    judged = err if friction_judged else {**err, "damping": math.inf, "tau_c": math.inf}
    if drive_identifiable:  # a gain within 3 se of zero: the command did not move the drive (exit 2)
        sense.check_excited(params, judged, str(data.path or data.name))
    reason = sense.baseline_problem(params, judged) if drive_identifiable else None
    if chosen is not None and reason is None:
        problem = sense.effect_problem(cause, effect_out, u, params["time_constant_s"], data.sample_rate_hz)
        if problem is not None:
            reason = f"the best extension, {cause}, {problem}"
    if reason is not None:
        cause, effect_out = "model_mismatch", {"reason": reason}
        mismatch = ("model_mismatch", f"the model does not fit this recording: {reason}")
        ranked = [
            Scored(s.cause, s.effect, s.z, s.p, False, why_not=mismatch) if s.significant else s
            for s in ranked
        ]
    th = gls(design.y, X_fin, out.ar, out.keep).theta
    residual = design.y - X_fin @ th
    return Verdict(ranked, cause, effect_out, reason, residual, X_fin, th, u_fin)


def _unconfirmed(instrumented: Confirmation, t: C.Tested) -> tuple[str, str]:
    """Why a cause the instrumented confirmation refused is not named: the refusal carries
    evidence only if the confirmation could have shown the effect least squares found
    (docs/measurements/whynot.md; two outsider drifts at z 12–20 were 1.1–1.7 of its errors)."""
    if t.option is None or t.coef is None:
        return WHY["not_instrumented"]
    power = instrumented.power(t.cause, t.option, t.coef)
    if power < NO_POWER:
        code, text = WHY["instrument_no_power"]
        return code, text.format(power=power)
    return WHY["not_instrumented"]


def _ls_alone(design: D.Design, out: C.Outcome, t: C.Tested, effect: dict[str, Any]) -> bool:
    """A cause whose confirmation had no power for it stands on least squares when its own second
    evidence is clean. A drift (rules.drift_ls_alone): it passed the gate, the windows' trend and
    the held-out folds already; the windows must also scatter no more than their errors
    (drift.ls_alone; outsider o12114, o13115: the effect 1.7 and 1.1 of the confirmation's errors
    at z 20 and 12). A direction split (rules.asym_ls_alone): the negative direction's visits in
    separate time windows agree on one split (asymmetry.ls_alone; outsider o14106: a 1.5 ratio at
    z 260, 1.5 of the confirmation's errors; closed null 910555, z 12.9, is refused by it)."""
    if t.coef is None or t.option is None:
        return False
    if t.cause == "drift" and design.rules.drift_ls_alone:
        return drift.ls_alone(design, out, str(effect["parameter"]), float(t.coef[0]))
    if t.cause == "friction_asymmetry" and design.rules.asym_ls_alone:
        return asymmetry.ls_alone(design, out, t.option.block, t.coef)
    return False


def _translate(
    cause: str, effect: dict[str, Any], th: np.ndarray, design: D.Design, J: float, k: int
) -> dict[str, Any]:
    """Free coefficients of the extended fit (its baseline `k` columns wide) → the cause's
    parameters (DESIGN.md names)."""
    names = dict(zip(design.names, th[:k], strict=False))
    extra = th[k:]
    if cause in ("imbalance", "cogging", "resonance") and len(extra) >= 2:
        cs, cc = float(extra[0]), float(extra[1])  # torque/J = cs·sin x + cc·cos x = (A/J)·sin(x + ψ)
        return {"amplitude": abs(J) * math.hypot(cs, cc), "phase": math.atan2(cc, cs)}
    if cause == "friction_asymmetry" and len(extra) >= 1:
        w = np.abs(design.prep.rows(design.prep.speed)[design.rows_mask])
        v = float(np.median(w)) if len(w) else 1.0
        tc, tf = names["c"], names["f"]
        cn = float(extra[0])
        fn = float(extra[1]) if len(extra) > 1 else 0.0
        kv_pos, kv_neg = -tc * J, -(tc + cn) * J
        tc_pos, tc_neg = -tf * J, -(tf + fn) * J
        # Which levels carry the ratio: the Coulomb ones where the split has them (a voltage
        # drive's slope holds kM·kb/R of an unknown motor; outsider_bench's asymmetry scales the
        # Coulomb levels only); with an offset in the baseline (a linear force axis, EMPS) the
        # Coulomb split is the offset's, so the viscous slopes (friction alone there) speak.
        if len(extra) > 1 and tc_pos > 0:
            ratio = tc_neg / tc_pos
        elif kv_pos > 0:
            ratio = kv_neg / kv_pos
        else:
            ratio = math.nan
        out = {
            "ratio": ratio,
            "at_speed": v,
            "kv_pos": kv_pos,
            "kv_neg": kv_neg,
            "tau_c_pos": tc_pos,
            "tau_c_neg": tc_neg,
        }
        if len(extra) > 1:
            # A constant torque c is the same model (dataset.offset_term): the Coulomb split
            # could equally be c = (τc₊ − τc₋)/2 in effort units, e.g. a drive's zero offset.
            out["offset_equivalent"] = (tc_pos - tc_neg) / 2
        return out
    if cause == "drift" and len(extra) >= 1:
        d = float(extra[0])
        p = effect.get("parameter")
        if p == "R":
            a = names["a0"] + names["a1"]
            g = d / a if a else math.nan
            return {"relative_change": 1.0 / (1.0 + g) - 1.0 if g > -1 else math.inf}
        ref = names["c"] if p == "kv" else names["f"]
        mask = design.rows_mask
        x = design.X[mask, design.names.index("c" if p == "kv" else "f")]
        coulomb = design.X[mask, design.names.index("f")]
        if np.all(coulomb > 0) or np.all(coulomb < 0):  # one way: relative to the resisting torque
            resist = sum(names[n] * design.X[mask, design.names.index(n)] for n in ("c", "f", "s"))
            ref = float(np.dot(resist, x) / max(float(x @ x), 1e-300))
        return {"relative_change": d / ref if ref else math.nan}
    return {}
