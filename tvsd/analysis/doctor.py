"""The model doctor: fit the paper's model, find what it gets wrong, name the cause, measure the gain.

1. Sense of the input (tvsd.analysis.sense): too short, constant, absurd → one line, exit 2.
2. Baseline: the paper's rigid model with every coefficient free (tvsd.analysis.design), so the
   motor need not be the config's; fitted by generalised least squares under an AR noise model.
3. Decision (tvsd.analysis.calibrate): every cause is an extension nesting the baseline; each is
   scored by its likelihood ratio, standardised by its own null distribution (parametric
   bootstrap from the fitted baseline and its noise), and the best is named only above the
   (1 − α) point of the bootstrap maxima. α = 1 %: the false-alarm rate, by construction.
4. Physical sense of what would be reported (sense.py): a baseline or a best extension with a
   negative inertia, a threshold outside the commands, … → `model_mismatch` and the reason.
5. Noise colour, when no deterministic cause is named: Whittle's likelihood ratio of a low-pass
   against a flat vibration spectrum on the residual rows (tvsd.analysis.noise).
6. Gain: the baseline and the extension fitted without the held-out part (the last third, or
   the whole file with --heldout), simulated from the recorded command there (restarted from the
   measured state every SIM_WINDOW_S), and their speed errors compared.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.stats import chi2

from tvsd.analysis import absorber, instrument, quantisation, selection, sense
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.noise import NoiseReport, analyse, on_declared_line, spectral_cause
from tvsd.analysis.prep import Band, prepare
from tvsd.analysis.rules import DEFAULT, Rules
from tvsd.analysis.simulate import ReducedModel, simulate
from tvsd.causes import Effect
from tvsd.model import effects as E

HOLDOUT_SPLIT = 2 / 3
SIM_WINDOW_S = 1.0
COLOUR_P = 1e-3  # the noise colour's likelihood ratio (χ², 1 dof) must beat this p-value
ALPHA = C.ALPHA
INPUT_CAUSES = ("deadzone", "saturation", "delay")

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Scored:
    cause: str
    effect: dict[str, Any]
    z: float  # likelihood ratio standardised by its own bootstrap null
    p: float  # bootstrap p-value of this cause alone
    significant: bool
    heldout_gain_pct: float = math.nan
    why_not: tuple[str, str] | None = None  # (code, sentence) when not named (verdict.WHY)


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


def _physical(
    design: D.Design, theta: np.ndarray, cov: np.ndarray, b_u: float, b_omega: float
) -> tuple[dict[str, float], dict[str, float]]:
    """Accelerations per unit column → the paper's parameters: J from the drive's input gain.

    The input gain is a₀ + a₁: the two columns (u now and one sample later) are nearly collinear,
    so their coefficients are strongly anti-correlated and the sum's standard error is far below
    either one's — it needs the covariance, not the two standard errors."""
    v = dict(zip(design.names, theta, strict=False))
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    s = dict(zip(design.names, se, strict=False))
    a = v["a0"] + v["a1"]
    i0, i1 = design.names.index("a0"), design.names.index("a1")
    se_a = math.sqrt(max(float(cov[i0, i0] + cov[i1, i1] + 2 * cov[i0, i1]), 0.0))
    J = b_u / a if a != 0 else math.nan
    p = {
        "input_gain": a,
        "J": J,
        "damping": -v["c"] * J,  # viscous + back-EMF, effort per unit speed
        "kv": -v["c"] * J - b_omega,  # viscous alone, with the config's back-EMF
        "tau_c": -v["f"] * J,
        "d_stribeck": -v["s"] * J,
        "v0": design.v0,
        "offset": -v.get("b", 0.0) * J,
        "time_constant_s": 1.0 / max(-v["c"], 1e-12),
    }
    err = {
        "damping": abs(s["c"] * J),
        "tau_c": abs(s["f"] * J),
        "J": abs(J) * se_a / abs(a) if a != 0 else math.inf,
        "input_gain": se_a,
    }
    return p, err


def _reduced(p: dict[str, float], b_u: float, extra: dict[str, float] | None = None) -> ReducedModel:
    extra = extra or {}
    return ReducedModel(
        J=p["J"] if p["J"] > 0 else 1e-9,
        kv=max(p["damping"], 0.0),
        tau_c=max(p["tau_c"], 0.0),
        d_stribeck=max(p["d_stribeck"], 0.0),
        v0=p["v0"],
        offset=p["offset"],
        b_u=b_u,
        b_omega=0.0,
        kv_neg_scale=extra.get("kv_neg_scale", 1.0),
        tc_neg_scale=extra.get("tc_neg_scale", 1.0),
    )


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
    rotary = data.units.axis == "rotary"
    say("preparing the regression (band-limited rows, baseline and candidate columns)")
    prep = prepare(data, band)
    design = absorber.absorb(D.build(prep, data.offset_term, rotary))
    design.rules = rules
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
        )
        design = absorber.absorb(instrumented)
        design.rules = rules
    design.back_emf = data.b_omega > 0 or data.u_unit == "V"
    note = _closed_loop_note(data)
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
    fit = C.gls(design.y, design.X, out.ar, out.keep)
    # The drive's parameters (and their physical checks) from the rigid model alone (a SIL
    # identify export's kv came out < 0 with the absorber's shapes in the fit).
    rigid = C.gls(design.y, absorber.rigid(design, design.X)[0], out.ar, out.keep)
    params, err = _physical(design, rigid.theta, rigid.cov, data.b_u, data.b_omega)
    from tvsd.analysis.verdict import name_cause  # the per-cause translation (effects, checks)

    say("naming the cause and checking it makes physical sense")
    closed_ls = "omega_ref" in data.refs and design is measured
    verdict = name_cause(
        design,
        out,
        fit,
        params,
        err,
        data,
        drive_identifiable=note is None,
        friction_judged=not closed_ls,
        instrumented=_instrumented_check(prep, data, rotary, measured, seed, rules) if closed_ls else None,
    )
    say("testing the noise colour")
    rate_rows = 1.0 / float(np.median(np.diff(prep.t_rows)))
    # An encoder-difference speed's quantisation: a known floor in both spectral shapes, and the
    # rows ramped in and out at the gaps (a hard edge leaks its f⁴ power into the lowest bins).
    resid = instrument.residual(measured, design, verdict)
    resid, floor = quantisation.gated(prep, out.keep, resid, rate_rows)
    noise = analyse(resid, rate_rows, params["J"] if params["J"] > 0 else 1.0, prep.band.cutoff_hz, floor)
    ranked = verdict.ranked
    # Closed loop: the feedback shapes the equation's residual (the command answers its noise,
    # and least squares on that command leaves part of the noise's answer in the residual), so
    # its colour says nothing of the vibration's — with a constant reference and with an excited
    # one alike (a white-vibration identify null was `colored_noise`, τ 5 ms); not a candidate
    # unless the reference instruments the fit (iv).
    colour_sig = noise.colour_p < COLOUR_P and note is None and not closed_ls
    ranked.append(
        Scored("colored_noise", {"tau_s": noise.tau_s}, noise.colour_lr, noise.colour_p, colour_sig)
    )
    cause, effect = verdict.cause, verdict.effect
    J = params["J"]
    # The peak is tested before the low-pass colour (noise.spectral_cause), not only once it fired.
    peak = note is None and spectral_cause(noise, COLOUR_P) == "resonance"
    peak = peak and not on_declared_line(noise, data.excitation_hz)  # the excitation's own line
    peak_amp = abs(J) * math.sqrt(2.0) * noise.peak_rms
    refuse = cause == "none" and peak and closed_ls
    if refuse and not _peak_in_plant(prep, data, rotary, measured, out.keep, noise, rules):
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
    why = _colour_why(noise, cause, closed=note is not None or closed_ls, peak=peak)
    ranked = [
        replace(s, why_not=why) if s.cause == "colored_noise" and not s.significant else s for s in ranked
    ]
    ranked.sort(key=lambda s: (s.cause != cause, not s.significant, -s.z))
    causes = _causes(design, out, verdict, cause, effect, ranked, params, err, data, seed, say)
    effect = causes[0].effect if causes else effect  # with its amplitude's standard error
    say("simulating baseline and extension on the held-out data")
    from tvsd.analysis.verdict import heldout_speed

    rmse_b, rmse_e, ext_params, sim = heldout_speed(design, out, data, heldout, band, cause, effect, verdict)
    return Diagnosis(
        data,
        design,
        out,
        params,
        err,
        _reduced(params, data.b_u),
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


def _colour_why(noise: NoiseReport, cause: str, closed: bool, peak: bool) -> tuple[str, str] | None:
    """Why coloured noise is not named: it is judged by its own spectral test (Whittle's
    likelihood ratio, low-pass against flat, χ²₁ at p < COLOUR_P), not by the z gate, and only
    when no deterministic cause is named and the loop is open."""
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


def _instrumented_check(
    prep: Any, data: Dataset, rotary: bool, measured: D.Design, seed: int, rules: Rules = DEFAULT
) -> Callable[[str], bool] | None:
    """Closed loop by least squares, with an excited reference: whether a command-side cause
    also passes the decision on the instrumented design (tvsd.analysis.instrument: every
    command and speed column from the reference's and identify's PRBS prediction, the left side
    cleaned to the structural residual), built once, on demand.

    The law answers the noise, so the measured command correlates with the equation's error:
    the bootstrap, which conditions on the regressors, is not the null of the least-squares
    command blocks (a clip at z 25.1 and a dead zone at z 5.4 on identify nulls, where the
    structural refits fitted too). The instrumented columns are functions of signals the noise
    does not move, so the same bootstrap is their null (the same two: z 0.8 and −0.1; the
    matrix's closed-loop clips and delays stay far above the gate: 293 and 83–1406)."""
    if not instrument.excited(data):
        return None
    memo: dict[tuple[bool, bool, bool], C.Outcome] = {}

    def holds(cause: str) -> bool:
        # Per cause (rules.identified_for, expected_for; docs/measurements/closedsat.md): the
        # clip's block as E[f(u) | instruments], θ_IV along identified directions only.
        key = (
            cause in rules.identified_for or rules.identified_only,
            cause in rules.expected_for or rules.expected_maps,
            cause in rules.spin_only_for,
        )
        if key not in memo:
            ident, expect, spin = key
            iv, _ = instrument.instrumented(prep, data.offset_term, rotary, expected=expect, spin_only=spin)
            iv = absorber.absorb(iv)
            iv.back_emf = measured.back_emf
            iv.rules = rules
            iv.y = instrument.structural_left_side(iv, measured, identified_only=ident)
            memo[key] = C.test_all(iv, seed=seed)
        out = memo[key]
        return any(t.cause == cause and t.z > out.threshold for t in out.tested)

    return holds


LOOP_PEAK = (
    "loop_peak",
    "closed loop: the residual's peak is not in the residual of the instrumented fit (the reference "
    "as instrument), so it is the loop's answer to the noise that least squares on the measured "
    "command leaves, not a mode of the plant",
)


def _peak_in_plant(
    prep: Any,
    data: Dataset,
    rotary: bool,
    measured: D.Design,
    keep: np.ndarray,
    noise: NoiseReport,
    rules: Rules = DEFAULT,
) -> bool:
    """Whether a residual peak of a closed-loop least-squares fit is the plant's: the law feeds
    the measured noise back into the command, so least squares on that command is biased and its
    residual keeps a share of the loop's answer to the noise — S = 1/(1 + PC) shaped, peaked at
    the loop's own mode when it is underdamped (an outsider PI loop's 10.6 Hz on a null,
    docs/measurements/loopmode.md). The instrumented fit's residual (y − X·θ_IV) is the
    equation's own error: a mode of the plant is a torque in it and stays; the bias, and with it
    the loop's peak, goes. The peak must be there too, within its half-power band."""
    if not instrument.excited(data):
        return False  # nothing to instrument with: a peak is not told from the loop's
    iv, _ = instrument.instrumented(prep, data.offset_term, rotary, expected=rules.expected_maps)
    resid = instrument.structural_residual(absorber.absorb(iv), measured)
    if resid is None:
        return False
    rate = 1.0 / float(np.median(np.diff(prep.t_rows)))
    gated, floor = quantisation.gated(prep, keep, resid, rate)
    again = analyse(gated, rate, 1.0, prep.band.cutoff_hz, floor)
    if spectral_cause(again, COLOUR_P) != "resonance":
        return False
    df = float(noise.freq[1] - noise.freq[0]) if len(noise.freq) > 1 else 0.0
    half = max(noise.peak_hz / (2.0 * noise.peak_q), df) if noise.peak_q > 0 else df
    return abs(again.peak_hz - noise.peak_hz) <= half


def _closed_loop_note(data: Dataset) -> str | None:
    if "omega_ref" not in data.refs or instrument.reference_moves(data):
        return None
    return (
        "closed loop with a constant reference: dead zone, saturation and delay are not testable "
        "(the command answers the noise); record with reference steps (tvsctl identify)"
    )


def simulate_speed(
    model: ReducedModel,
    data: Dataset,
    command: np.ndarray,
    eff: np.ndarray | None,
    window_s: float = SIM_WINDOW_S,
) -> np.ndarray:
    speed = data.speed if data.speed is not None else np.gradient(data.position, data.t)
    w, _ = simulate(
        model, data.t, command, E.neutral() if eff is None else eff, speed, data.position, window_s
    )
    return w


def effect_array(cause: str, effect: dict[str, Any]) -> np.ndarray | None:
    keep = {
        "imbalance": ("amplitude", "phase"),
        "cogging": ("order", "amplitude", "phase"),
        "resonance": ("frequency_hz", "amplitude", "phase"),
        "saturation": ("u_max",),
        "deadzone": ("u0",),
    }.get(cause)
    if keep is None:
        return None
    return E.pack([Effect(cause, {k: effect[k] for k in keep if k in effect})])
