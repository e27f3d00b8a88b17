"""The model doctor: fit the paper's model, find what it gets wrong, name the cause, measure the gain.

1. Sense of the input (tvsd.analysis.sense): too short, constant, absurd → one line, exit 2;
   a shaft that never moves clear of its speed noise (tvsd.analysis.excitation) → the same.
2. Baseline: the paper's rigid model with every coefficient free (tvsd.analysis.design), so the
   motor need not be the config's; fitted by generalised least squares under an AR noise model
   (tvsd.analysis.gls), its coefficients read as the paper's parameters (tvsd.analysis.physical).
3. Decision (tvsd.analysis.calibrate): every cause is an extension nesting the baseline; each is
   scored by its likelihood ratio, standardised by its own null distribution (parametric
   bootstrap from the fitted baseline and its noise), and the best is named only above the
   (1 − α) point of the bootstrap maxima. α = 1 %: the false-alarm rate, by construction.
4. Naming (tvsd.analysis.verdict), with the physical sense of what would be reported (sense.py):
   a baseline or a best extension with a negative inertia, a threshold outside the commands, … →
   `model_mismatch` and the reason. In closed loop a command-side cause, and a residual peak, are
   checked on the instrumented design too (tvsd.analysis.closed_checks).
5. Noise colour, when no deterministic cause is named: Whittle's likelihood ratio of a low-pass
   against a flat vibration spectrum on the residual rows (tvsd.analysis.noise).
6. Gain: the baseline and the extension fitted without the held-out part (the last third, or
   the whole file with --heldout), simulated from the recorded command there (restarted from the
   measured state every SIM_WINDOW_S), and their speed errors compared (tvsd.analysis.heldout_sim).

This module orchestrates those steps and assembles the Diagnosis.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.stats import chi2

from tvsd.analysis import (
    absorber,
    excitation,
    heldout_sim,
    instrument,
    level_nuisance,
    selection,
    sense,
    spectral_fit,
    speed_source,
)
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.closed_checks import (
    LOOP_PEAK,
    closed_loop_note,
    instrumented_check,
    peak_in_plant,
    plant_noise,
)
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.gls import gls
from tvsd.analysis.linescan import command_lines_hz, excitation_rows
from tvsd.analysis.noise import COLOUR_P, NoiseReport, analyse, spectral_cause
from tvsd.analysis.peak import on_declared_line
from tvsd.analysis.physical import physical, reduced
from tvsd.analysis.prep import Band, prepare
from tvsd.analysis.rowgain import rows_gain
from tvsd.analysis.rules import DEFAULT, Rules
from tvsd.analysis.simulate import ReducedModel
from tvsd.analysis.verdict import Scored, name_cause

ALPHA = C.ALPHA

Progress = Callable[[str], None]


@dataclass
class Diagnosis:
    data: Dataset
    design: D.Design
    outcome: C.Outcome
    params: dict[str, float]  # baseline, physical units
    stderr: dict[str, float]
    model: ReducedModel
    ranked: list[Scored]
    cause: str
    effect: dict[str, Any]
    reason: str | None  # why the model does not fit (model_mismatch)
    noise: NoiseReport
    heldout_rmse_base: float
    heldout_rmse_ext: float
    ext_params: dict[str, float] = field(default_factory=dict)
    sim: dict[str, np.ndarray] = field(default_factory=dict)
    heldout_file: bool = False
    v0_config: float = math.nan  # the config's Stribeck speed (the IDIM-LS reference fit uses it)
    causes: list[selection.Named] = field(default_factory=list)  # every cause named, `cause` first

    @property
    def gain_pct(self) -> float:
        if not self.heldout_rmse_base or not math.isfinite(self.heldout_rmse_ext):
            return 0.0
        return 100.0 * (1.0 - self.heldout_rmse_ext / self.heldout_rmse_base)


def diagnose(
    data: Dataset,
    v0: float,
    heldout: Dataset | None = None,
    band: Band | None = None,
    progress: Progress | None = None,
    seed: int = 0,
    iv: bool = False,
    rules: Rules = DEFAULT,
) -> Diagnosis:
    """The doctor on one recording. BLAS runs on one thread: its threads spin-wait, which cost
    a third of the CPU on 2 cores (more under load), and its reductions' order follows the
    thread count, which moved every bootstrap z by ~1 % between machines (the null's draws pass
    through an eigendecomposition of a nearly degenerate Gram matrix). `rules`: the switchable
    rules (tvsd.analysis.rules; the closed-loop matrix's variants)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        return _diagnose(data, v0, heldout, band, progress, seed, iv, rules)


def _diagnose(
    data: Dataset,
    v0: float,
    heldout: Dataset | None,
    band: Band | None,
    progress: Progress | None,
    seed: int,
    iv: bool,
    rules: Rules,
) -> Diagnosis:
    say = progress or (lambda _msg: None)
    sense.check_recording(data)
    if heldout is not None:
        sense.check_recording(heldout)
    band = band or Band()
    # A noisy speed column beside an encoder: the count difference when it fits far better.
    recorded, recorded_heldout = data, heldout
    chosen = speed_source.choose(data, band)
    if chosen is not data:
        data = chosen
        if heldout is not None:
            heldout = speed_source.same_source(heldout, data)
    rotary = data.units.axis == "rotary"
    say("preparing the regression (band-limited rows, baseline and candidate columns)")
    prep = prepare(data, band)
    design = absorber.absorb(D.build(prep, data.offset_term, rotary, rules=rules))
    if speed_source.KEY in data.meta:  # through the encoder: the drive's per-level error in the null
        design.levels = level_nuisance.columns(prep)
        if design.levels is not None:  # said with the speed's note (the verdict's warning)
            data.meta[speed_source.KEY] += "; " + level_nuisance.NOTE.format(design.levels.columns.shape[1])
    excitation.check_moving(prep, design.X.shape[1])  # a stuck drive: no excitation, exit 2
    if data is not recorded:  # read through the encoder: the recording's own speed must move too
        excitation.check_recorded(prepare(recorded, band), prep, design.X.shape[1])
    if heldout is not None:  # judged on: a stuck held-out file would judge the model on noise
        heldout_prep = prepare(heldout, band)
        excitation.check_moving(heldout_prep, design.X.shape[1])
        if heldout is not recorded_heldout and recorded_heldout is not None:
            excitation.check_recorded(prepare(recorded_heldout, band), heldout_prep, design.X.shape[1])
    measured = design
    if iv and instrument.excited(data):  # closed loop, excited: 2SLS (opt-in,
        # docs/measurements/doctor-closed.md)
        instrumented, _ = instrument.instrumented(
            prep,
            data.offset_term,
            rotary,
            measured=measured,
            expected=rules.expected_maps,
            identified_only=rules.identified_only,
            rules=rules,
        )
        design = absorber.absorb(instrumented)
    design.back_emf = data.b_omega > 0 or data.u_unit == "V"
    note = closed_loop_note(data)
    if note is not None:
        # In closed loop the command answers the noise; a map of the command (threshold, clip,
        # delay) is identifiable only through an excited reference, so without one it is not
        # a candidate (tvsctl identify excites it).
        for cause in D.INPUT_CAUSES:
            design.options.pop(cause, None)
    if np.count_nonzero(design.rows_mask) < 10 * design.X.shape[1]:
        raise sense.DataFileError(
            f"{data.path or data.name}: the shaft moves in too few samples to identify the drive "
            "(excite it harder or longer)"
        )
    say("testing every cause against the bootstrap null of the fitted baseline")
    out = C.test_all(design, seed=seed)
    fit = gls(design.y, design.X, out.ar, out.keep)
    # The drive's parameters (and their physical checks) from the rigid model alone (a SIL
    # identify export's kv came out < 0 with the absorber's shapes in the fit).
    rigid = gls(design.y, absorber.rigid(design, design.X)[0], out.ar, out.keep)
    params, err = physical(design, rigid.theta, rigid.cov, data.b_u, data.b_omega)
    say("naming the cause and checking it makes physical sense")
    closed_ls = data.closed_loop and design is measured
    verdict = name_cause(
        design,
        out,
        fit,
        params,
        err,
        data,
        drive_identifiable=note is None,
        friction_judged=not closed_ls,
        instrumented=instrumented_check(prep, data, rotary, measured, seed, rules) if closed_ls else None,
    )
    say("testing the noise colour")
    rate_rows = 1.0 / float(np.median(np.diff(prep.t_rows)))
    # An encoder-difference speed's quantisation: a known floor in both spectral shapes, and the
    # rows ramped in and out at the gaps (a hard edge leaks its f⁴ power into the lowest bins).
    resid = instrument.residual(measured, design, verdict)
    model = (verdict.X, out.ar) if design is measured else None  # the levels refitted with the model
    resid, floor = spectral_fit.refit(prep, out.keep, resid, rate_rows, model)
    J_noise = params["J"] if params["J"] > 0 else 1.0
    noise = analyse(resid, rate_rows, J_noise, prep.band.cutoff_hz, floor, rows_gain(prep))
    ranked = verdict.ranked
    cause, effect = verdict.cause, verdict.effect
    J = params["J"]
    # The peak is tested before the low-pass colour (noise.spectral_cause), not only once it fired.
    peak = note is None and spectral_cause(noise, COLOUR_P) == "resonance"
    # Not on the excitation's own lines: declared, or detected in the command as the line scan
    # leaves them out (a multisine's top line misfit by the rigid model is a narrow peak).
    lines = data.excitation_hz + command_lines_hz([x[out.keep] for x in excitation_rows(design)], rate_rows)
    peak = peak and not on_declared_line(noise, lines)
    peak_amp = abs(J) * math.sqrt(2.0) * noise.peak_rms
    refuse = cause == "none" and peak and closed_ls
    loop_peak = refuse and not peak_in_plant(
        noise, plant_noise(prep, data, rotary, measured, out.keep, rules)
    )
    # Closed loop: with a constant reference not a candidate (nothing instruments the fit, and no
    # null was measured). With an excited reference by least squares, under rules.closed_colour
    # (on by default): the fit on the measured command takes out of the residual the share of the
    # noise the law answers, inside the loop's band, which flattens the spectrum's low end rather
    # than raising it; the offline matrix's closed-loop nulls and SIL daemon identify null exports
    # (with the interpolated angle's quantisation floor) stay under the test's χ² level
    # (docs/measurements/closedcolour.md, closedcolour2.md). Only with identify's voltage
    # excitation (u_exc): a scan with a reference step and no excitation left a τ 14 ms colour at
    # likelihood ratio 94 (tests/data/walk's make-run recording, nothing hidden: white up to its first
    # command step, coloured over it), and with any moving reference the outsider's closed nulls
    # name it 20/232 (closedcolour3.md). Never when the residual's peak is the loop's (loop_peak):
    # then its shape is the loop's, not the vibration's.
    excited = _identify_excited(data) or not rules.closed_colour_u_exc
    colour_judged = closed_ls and rules.closed_colour and excited
    closed_ok = not closed_ls or (colour_judged and not loop_peak)
    colour_sig = noise.colour_p < COLOUR_P and note is None and closed_ok
    ranked.append(
        Scored("colored_noise", {"tau_s": noise.tau_s}, noise.colour_lr, noise.colour_p, colour_sig)
    )
    if loop_peak:
        # Closed loop by least squares: a peak the instrumented fit does not leave is not the plant's.
        loop = {"frequency_hz": noise.peak_hz, "amplitude": peak_amp, "q": noise.peak_q}
        p_peak = float(chi2.sf(noise.peak_lr, 2))
        ranked.append(Scored("resonance", loop, noise.peak_lr, p_peak, False, why_not=LOOP_PEAK))
        peak = False
    if cause == "none" and peak:
        # Coloured, and the colour is a narrow peak: a structural mode, not a low-pass disturbance.
        cause, effect = "resonance", {"frequency_hz": noise.peak_hz, "amplitude": peak_amp, "q": noise.peak_q}
        ranked.append(Scored("resonance", effect, noise.peak_lr, float(chi2.sf(noise.peak_lr, 2)), True))
    elif cause == "none" and colour_sig:
        cause, effect = "colored_noise", {"tau_s": noise.tau_s}
    elif cause == "resonance" and peak and abs(noise.peak_hz - float(effect["frequency_hz"])) < 2.0:
        # A line and a peak at the same place: a mode rung partly coherently; both carry its torque.
        effect = {
            **effect,
            "frequency_hz": noise.peak_hz,
            "amplitude": math.hypot(float(effect["amplitude"]), peak_amp),
            "q": noise.peak_q,
        }
    closed = note is not None or (closed_ls and not colour_judged)
    why = _colour_why(noise, cause, closed=closed, peak=peak, loop_peak=loop_peak)
    ranked = [
        replace(s, why_not=why) if s.cause == "colored_noise" and not s.significant else s for s in ranked
    ]
    ranked.sort(key=lambda s: (s.cause != cause, not s.significant, -s.z))
    causes = _causes(design, out, verdict, cause, effect, ranked, params, err, data, seed, say)
    effect = causes[0].effect if causes else effect  # with its amplitude's standard error
    say("simulating baseline and extension on the held-out data")
    # Through the module: the matrix tools skip it (matrix_open.heldout_gain_skipped).
    rmse_b, rmse_e, ext_params, sim = heldout_sim.heldout_speed(
        design, out, data, heldout, band, cause, effect, verdict
    )
    return Diagnosis(
        data,
        design,
        out,
        params,
        err,
        reduced(params, data.b_u),
        ranked,
        cause,
        effect,
        verdict.reason,
        noise,
        rmse_b,
        rmse_e,
        ext_params,
        sim,
        heldout is not None,
        v0,
        causes,
    )


def _identify_excited(data: Dataset) -> bool:
    """Whether identify's voltage excitation (the u_exc column) played in the file."""
    exc = data.refs.get(instrument.EXCITATION)
    return exc is not None and float(np.std(exc)) > 0


def _colour_why(
    noise: NoiseReport, cause: str, closed: bool, peak: bool, loop_peak: bool = False
) -> tuple[str, str] | None:
    """Why coloured noise is not named: it is judged by its own spectral test (Whittle's
    likelihood ratio, low-pass against flat, χ²₁ at p < COLOUR_P), not by the z gate, and only
    when no deterministic cause is named, and in closed loop only with an excited reference and
    no loop peak in the residual."""
    if cause == "colored_noise":
        return None
    test = (
        f"its score is Whittle's likelihood ratio of a low-pass against a flat residual spectrum "
        f"(p = {noise.colour_p:.3g}), judged by that spectral test, not by the z gate"
    )
    if closed:
        return (
            "closed_loop_colour",
            f"closed loop: the feedback shapes the residual's spectrum, so its colour says nothing "
            f"of the vibration's; {test}",
        )
    if noise.colour_p >= COLOUR_P:
        return ("spectral_test", f"{test}, and it needs p < {COLOUR_P:g}")
    if loop_peak:
        return (
            "loop_shaped",
            "closed loop: the residual's spectrum holds the loop's own peak (not in the instrumented "
            "fit's residual), so its shape is the loop's, not the vibration's",
        )
    if peak:
        return ("spectral_peak", "the residual's colour is a narrow peak: a structural mode (resonance)")
    return (
        "deterministic_first",
        f"{cause} is named; the noise colour is judged only when no deterministic cause is ({test})",
    )


def _causes(
    design: D.Design,
    out: C.Outcome,
    verdict: Any,
    cause: str,
    effect: dict[str, Any],
    ranked: list[Scored],
    params: dict[str, float],
    err: dict[str, float],
    data: Dataset,
    seed: int,
    say: Progress,
) -> list[selection.Named]:
    """The ranked list: empty for `none`; the top cause, then (when the decision named it) every
    further cause forward selection finds (tvsd.analysis.selection)."""
    if cause == "none":
        return []
    top = next((s for s in ranked if s.cause == cause), None)
    decided = cause == verdict.cause and cause != "model_mismatch"
    gain = selection.cv_gain(design, out, verdict) if decided else math.nan
    se = selection.amplitude_se(design, out, verdict, params["J"], err["J"]) if decided else {}
    first = selection.Named(
        cause,
        {**effect, **se},
        top.z if top is not None else math.nan,
        out.threshold if decided else math.nan,  # a spectral cause has its own test (noise.py)
        top.p if top is not None else math.nan,
        gain,
        1,
    )
    if not decided:
        return [first]
    say("testing the other causes against the model extended by the named one")
    return [first, *selection.further(design, verdict, params, err, data, seed)]
