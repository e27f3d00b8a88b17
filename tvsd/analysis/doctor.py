"""The model doctor: fit the paper's model, find what it gets wrong, name the cause, measure the gain.

1. Baseline: the paper's model by IDIM-IV (tvsd.analysis.baseline) on the fitting part.
2. Candidates: every cause of the vocabulary fitted as an extension (tvsd.analysis.candidates);
   scanned parameters by least squares, then the extension refitted by IV with instruments from
   its own simulation.
3. Decision on data not used for fitting: with r the baseline's held-out residual and δ the
   difference of the two models' predictions there (fixed by the fitting part), the candidate's
   residual power changes by ΔRSS = 2·r·δ − |δ|². If the candidate explains nothing, r is noise
   independent of δ and z = ΔRSS / (2·sd(r·δ)) is at most standard normal; Z_CRIT names the
   cause. r is not white (the speed's random walk between instrument restarts is in it), so
   sd(Σ r·δ) is the Newey–West estimate over the restart horizon, not σ·|δ|.
   Two more conditions guard against what the equation error alone gets wrong: the extension
   must remove at least MIN_GAIN_PCT of the held-out residual power, and the extended model,
   simulated from the command, must not track the held-out speed worse than the baseline.
   (Under the vibration, the equation error systematically favours a small dead zone or a
   kM drift on recordings with no effect at all; simulated, these make the speed 75–600 %
   worse, while every real effect improves it or leaves it within 3 %.)
   An in-sample fit to noise does not carry over to unseen data, so a null recording comes out
   `none`. The noise colour is tested on the residual of the chosen model.
4. Gain: speed RMSE of the model simulated from the recorded command on the held-out part,
   restarted from the measured state every SIM_WINDOW_S (the windowed simulation error).
5. A line fixed in Hz and a shaft-locked torque are told apart only where the speed changes. When
   the winning resonance sits on a shaft order of a steady-speed held-out segment, the data
   cannot separate them: the shaft-locked cause (imbalance at order 1, cogging above) is named,
   with its own fitted parameters, and `ambiguous_with` says so (the paper's Table 2 case).
Without --heldout the first HOLDOUT_SPLIT of the recording is fitted and the rest held out.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tvsd.analysis import baseline as B
from tvsd.analysis.candidates import DETERMINISTIC, Candidate
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.inverse import Columns, Fit
from tvsd.analysis.noise import NoiseReport, analyse
from tvsd.analysis.prep import Band, prepare
from tvsd.analysis.simulate import ReducedModel, simulate
from tvsd.model import effects as E

HOLDOUT_SPLIT = 2 / 3
SHAFT_LOCKED = ("imbalance", "cogging")
# One-sided z above 5 is p ≈ 3e-7; the margin covers the 8-candidate Bonferroni factor and the
# Newey–West estimate's own uncertainty.
Z_CRIT = 5.0
COLOUR_P = 1e-6  # the noise-colour likelihood ratio must beat this p-value (χ², 1 dof)
SIM_WINDOW_S = 1.0
STEADY_SPEED_CV = 0.05  # a held-out segment with speed std/mean below this is "steady"
ORDER_MATCH = 0.02  # a line within 2 % of k × rotation rate sits on shaft order k
MIN_GAIN_PCT = 0.5  # a cause must explain at least this share of what the baseline misses
SIM_TOLERANCE = 1.10  # the extension may track the held-out speed at most 10 % worse (see above)

Progress = Callable[[str], None]


@dataclass(frozen=True)
class Scored:
    candidate: Candidate | None  # None for colored_noise
    cause: str
    effect: dict[str, Any]
    z: float  # held-out z-score (likelihood ratio for the noise colour)
    heldout_gain_pct: float  # held-out residual power removed, %
    significant: bool
    fit: Fit | None = None
    sim_rmse: float = math.nan  # held-out speed RMSE of the extension, simulated
    ambiguous_with: str | None = None  # a cause the held-out data cannot tell apart from this one


@dataclass
class Diagnosis:
    data: Dataset
    baseline: B.Baseline
    ranked: list[Scored]
    noise: NoiseReport
    heldout_rmse_base: float
    heldout_rmse_ext: float
    cols: Columns
    heldout_cols: Columns | None
    sim: dict[str, np.ndarray] = field(default_factory=dict)  # traces for the report

    @property
    def best(self) -> Scored | None:
        return self.ranked[0] if self.ranked and self.ranked[0].significant else None

    @property
    def cause(self) -> str:
        return self.best.cause if self.best else "none"

    @property
    def gain_pct(self) -> float:
        if not self.heldout_rmse_base:
            return 0.0
        return 100.0 * (1.0 - self.heldout_rmse_ext / self.heldout_rmse_base)


def _model(cols: Columns, fit: Fit, cand: Candidate | None) -> ReducedModel:
    """The reduced model of a fit; friction split by direction when the fit has it."""
    base = B.reduced_model(cols, fit)
    if "kv_pos" not in fit.names:
        return base
    kv_pos, tc_pos = fit.value("kv_pos"), fit.value("tau_c_pos")
    e = {"kv_neg": fit.value("kv_neg"), "tau_c_neg": fit.value("tau_c_neg")}
    return ReducedModel(
        J=base.J,
        kv=max(kv_pos, 0.0),
        tau_c=max(tc_pos, 0.0),
        d_stribeck=0.0,
        v0=base.v0,
        offset=base.offset,
        b_u=base.b_u,
        b_omega=base.b_omega,
        kv_neg_scale=float(e["kv_neg"]) / kv_pos if kv_pos > 0 else 1.0,
        tc_neg_scale=float(e["tau_c_neg"]) / tc_pos if tc_pos > 0 else 1.0,
    )


def _effect_array(cand: Candidate | None) -> np.ndarray:
    if cand is None or cand.cause in ("friction_asymmetry", "delay"):
        return E.neutral()  # asymmetry is in the model; delay is applied to the command
    return cand.effect_array()


def _with_effect(cand: Candidate, effect: dict[str, Any]) -> Candidate:
    return Candidate(
        cand.cause, effect, cand.fit, cand.delta_bic, cand.builders, cand.y_of, cand.input_transform
    )


def _command(cols: Columns, cand: Candidate | None) -> np.ndarray:
    u = B.lagged_command(cols)
    if cand is not None and cand.cause == "delay":
        d = cols.prep.data
        u = np.interp(d.t - float(cand.effect["delay_s"]), d.t, u, left=0.0)
    return u


def _simulate(cols: Columns, fit: Fit, cand: Candidate | None, window_s: float) -> np.ndarray:
    d = cols.prep.data
    w, _ = simulate(
        _model(cols, fit, cand),
        d.t,
        _command(cols, cand),
        _effect_array(cand),
        B.measured_speed(cols),
        d.position,
        window_s=window_s,
    )
    return w


# Causes whose extra columns are sinusoids of the measured angle or of time: exogenous, so they
# are detected by least squares on the structural residual, baseline and extension alike (the
# vibration's bias on J is then common to both). Instruments would hurt here: in closed loop the
# command holds the controller's answer to the very torque sought, and a J column simulated from
# that command is collinear with the sinusoid. The simulation check still uses IV parameters.
SINUSOIDS = ("imbalance", "cogging", "resonance")


def _refit(cols: Columns, cand: Candidate) -> tuple[Fit, Fit, Fit]:
    """(extension, baseline) fitted the same way so they differ by the extension only, and the
    fit whose J, kv, τc the simulation check uses (IV with the extension's instruments)."""
    cols.use_instruments(_simulate(cols, cand.fit, cand, B.INSTRUMENT_WINDOW_S))
    ext_iv, base_iv = cols.fit(cand.y_of(cols), cand.builders), cols.baseline()
    if cand.cause not in SINUSOIDS:
        return ext_iv, base_iv, ext_iv
    cols.use_instruments(None)
    return cols.fit(cand.y_of(cols), cand.builders), cols.baseline(), ext_iv


def _newey_west_sum_var(x: np.ndarray, lags: int) -> float:
    """Variance of Σx for a stationary, autocorrelated x (Bartlett-weighted autocovariances)."""
    x = x - x.mean()
    n = len(x)
    var = float(x @ x)
    for lag in range(1, min(lags, n - 1) + 1):
        var += 2.0 * (1.0 - lag / (lags + 1)) * float(x[:-lag] @ x[lag:])
    return max(var, 0.0) * n / max(n - 1, 1)


def _heldout_test(r_base: np.ndarray, r_cand: np.ndarray, lags: int) -> tuple[float, float]:
    """z-score of the held-out improvement, and % of held-out residual power removed."""
    delta = r_base - r_cand  # the two models' predictions differ by δ
    drss = float(r_base @ r_base - r_cand @ r_cand)
    # Under the null r_cand ≈ noise: ΔRSS = 2·Σ r·δ − |δ|², with r·δ using the candidate's residual.
    sd = math.sqrt(_newey_west_sum_var(r_cand * delta, lags))
    z = drss / (2 * sd) if sd > 0 else 0.0
    gain = 100.0 * drss / float(r_base @ r_base)
    return z, gain


def diagnose(
    data: Dataset,
    v0: float,
    heldout: Dataset | None = None,
    band: Band | None = None,
    progress: Progress | None = None,
) -> Diagnosis:
    say = progress or (lambda _msg: None)
    band = band or Band()
    cols = Columns(prepare(data, band), v0)
    held: Columns | None = None
    if heldout is None:
        cols.hold_out_after(HOLDOUT_SPLIT)
    else:
        held = Columns(prepare(heldout, band), v0)
        held.fit_rows = np.zeros(len(held.y), dtype=bool)
    eval_cols = held if held is not None else cols

    say("fitting the paper's model (static map, IDIM-LS, IDIM-IV)")
    base = B.fit_baseline(cols)

    rows_per_s = 1.0 / float(np.median(np.diff(cols.prep.t_rows)))
    lags = int(B.INSTRUMENT_WINDOW_S * rows_per_s)
    say("fitting candidate extensions")
    cols.use_instruments(None)
    base_ls = cols.baseline()
    speed = HeldoutSpeed(cols, held, base.fit)
    scored = _score(cols, eval_cols, base_ls, speed, lags, say, exclude=())
    first = max(scored, key=lambda c: (c.significant, c.heldout_gain_pct))
    if first.significant and first.candidate is not None:
        # Second pass: the other causes, on top of the first (two effects at once).
        say(f"testing the other causes on top of {first.cause}")
        c = first.candidate
        cols2 = cols.extended(c.y_of(cols), c.builders, c.input_transform)
        eval2 = (
            cols2 if held is None else eval_cols.extended(c.y_of(eval_cols), c.builders, c.input_transform)
        )
        cols2.use_instruments(None)
        again = _score(cols2, eval2, cols2.baseline(), speed, lags, say, exclude=(first.cause,))
        scored = [first, *again]
    say("testing the noise colour")
    rate_rows = 1.0 / float(np.median(np.diff(cols.prep.t_rows)))
    deterministic = max(scored, key=lambda c: c.z)
    residual = (
        deterministic.fit.residual if deterministic.significant and deterministic.fit else base.fit.residual
    )
    noise = analyse(residual, rate_rows, base.fit.value("J"), cols.prep.band.cutoff_hz)
    colour_ok = noise.colour_p < COLOUR_P
    scored.append(Scored(None, "colored_noise", {"tau_s": noise.tau_s}, noise.colour_lr, 0.0, colour_ok))

    # Significant deterministic causes rank by what they explain (the stronger named first); the
    # noise colour, a different kind of evidence, follows them and precedes the rest, which rank
    # by z.
    def key(s: Scored) -> tuple[int, float]:
        if s.cause == "colored_noise":
            return (1 if s.significant else 3, -s.z)
        return (0, -s.heldout_gain_pct) if s.significant else (2, -s.z)

    scored.sort(key=key)
    scored = _shaft_order_rule(scored, eval_cols)
    say("simulating baseline and extension on the held-out data")
    best = scored[0] if scored[0].significant else None
    rmse_ext, w_ext = speed.base_rmse, speed.base_speed
    if best is not None and best.candidate is not None and best.fit is not None:
        rmse_ext, w_ext = speed.rmse(best.fit, best.candidate)
    return Diagnosis(data, base, scored, noise, speed.base_rmse, rmse_ext, cols, held, speed.traces(w_ext))


def _explains_fitting_data(ext: Fit, base: Fit) -> bool:
    """An extension must also leave less unexplained on the data it was fitted on (structural
    residual y − X·θ, the inverse model's own error)."""
    return float(ext.residual @ ext.residual) < float(base.residual @ base.residual)


def _resolvable(cand: Candidate, rate_hz: float) -> bool:
    """A recording cannot resolve a transport delay shorter than its sample period: below it, the
    sample-and-hold of the command and the band filter's phase blur it."""
    return cand.cause != "delay" or float(cand.effect["delay_s"]) >= 1.0 / rate_hz


def _score(
    cols: Columns,
    eval_cols: Columns,
    base_ls: Fit,
    speed: HeldoutSpeed,
    lags: int,
    say: Progress,
    exclude: tuple[str, ...],
) -> list[Scored]:
    """Fit every cause as an extension of cols' model and judge it on the held-out rows."""
    scored: list[Scored] = []
    for name, fit_cause in DETERMINISTIC.items():
        if name in exclude or (name in SHAFT_LOCKED and cols.prep.data.units.axis != "rotary"):
            continue  # a linear axis has no revolution to lock to
        say(f"  {name}")
        cols.use_instruments(None)
        found = fit_cause(cols, base_ls)
        best_of_cause: Scored | None = None
        for cand in found if isinstance(found, list) else [found]:
            fit, paired_base, sim_fit = _refit(cols, cand)
            r = eval_cols.heldout_residual(cand.y_of(eval_cols), cand.builders, fit)
            r0 = eval_cols.heldout_residual(eval_cols.y, cols.base, paired_base)
            z, gain = _heldout_test(r0, r, lags)
            sim = math.nan
            effect = _report_effect(cand, fit, set(cols.base))
            cand = _with_effect(cand, effect)  # simulate with the fitted amplitudes and phases
            if z > Z_CRIT and gain >= MIN_GAIN_PCT:
                sim = speed.rmse(sim_fit, cand)[0]
            significant = (
                z > Z_CRIT
                and gain >= MIN_GAIN_PCT
                and sim <= SIM_TOLERANCE * speed.base_rmse
                and _explains_fitting_data(fit, paired_base)
                and _resolvable(cand, cols.prep.data.sample_rate_hz)
            )
            this = Scored(cand, name, effect, z, gain, significant, sim_fit, sim)
            if best_of_cause is None or (this.significant, this.z) > (
                best_of_cause.significant,
                best_of_cause.z,
            ):
                best_of_cause = this
        if best_of_cause is not None:
            scored.append(best_of_cause)
    return scored


def _shaft_order_rule(scored: list[Scored], eval_cols: Columns) -> list[Scored]:
    top = scored[0]
    if not (top.significant and top.cause == "resonance"):
        return scored
    w = np.abs(eval_cols.prep.rows(eval_cols.prep.speed)[~eval_cols.fit_rows])
    mean = float(np.mean(w))
    if mean <= 0 or float(np.std(w)) / mean > STEADY_SPEED_CV:
        return scored
    f_rot = mean / (2 * math.pi)
    order = round(float(top.effect["frequency_hz"]) / f_rot)
    if order < 1 or abs(float(top.effect["frequency_hz"]) - order * f_rot) > ORDER_MATCH * order * f_rot:
        return scored
    locked = "imbalance" if order == 1 else "cogging"
    match = next((s for s in scored if s.cause == locked), None)
    if match is None or (locked == "cogging" and match.effect.get("order") != order):
        return scored
    promoted = Scored(
        match.candidate,
        locked,
        match.effect,
        top.z,
        top.heldout_gain_pct,
        True,
        match.fit,
        match.sim_rmse,
        ambiguous_with="resonance",
    )
    demoted = Scored(
        top.candidate,
        top.cause,
        top.effect,
        top.z,
        top.heldout_gain_pct,
        False,
        top.fit,
        top.sim_rmse,
        ambiguous_with=locked,
    )
    rest = [s for s in scored[1:] if s is not match]
    return [promoted, demoted, *rest]


class HeldoutSpeed:
    """Speed RMSE on the held-out part of a model simulated from the recorded command, restarted
    from the measured state every SIM_WINDOW_S. The baseline is simulated once; each extension
    then simulates only itself."""

    def __init__(self, cols: Columns, held: Columns | None, base_fit: Fit) -> None:
        self.target = held if held is not None else cols
        d = self.target.prep.data
        self.mask = np.ones(len(d.t), dtype=bool)
        if held is None:
            self.mask = d.t >= d.t[0] + HOLDOUT_SPLIT * (d.t[-1] - d.t[0])
        self.measured = d.speed if d.speed is not None else self.target.prep.speed
        self.base_rmse, self.base_speed = self.rmse(base_fit, None)

    def rmse(self, fit: Fit, cand: Candidate | None) -> tuple[float, np.ndarray]:
        w = _simulate(self.target, fit, cand, SIM_WINDOW_S)
        return float(np.sqrt(np.mean((w - self.measured)[self.mask] ** 2))), w

    def traces(self, extended: np.ndarray) -> dict[str, np.ndarray]:
        """For the report."""
        return {
            "t": self.target.prep.data.t,
            "measured": self.measured,
            "baseline": self.base_speed,
            "extended": extended,
            "heldout": self.mask,
        }


def _report_effect(cand: Candidate, fit: Fit, base_names: set[str]) -> dict[str, Any]:
    """The cause's parameters (DESIGN.md names), amplitudes and phases from the refit."""
    effect: dict[str, Any] = dict(cand.effect)
    for s_name, c_name in (("s1", "c1"), ("sN", "cN"), ("sR", "cR")):
        if s_name in fit.names and s_name not in base_names:
            # −A·sin(x + ψ) = cs·sin x + cc·cos x on the effort side
            cs, cc = fit.value(s_name), fit.value(c_name)
            effect["amplitude"] = math.hypot(cs, cc)
            effect["phase"] = math.atan2(-cc, -cs)
    return effect
