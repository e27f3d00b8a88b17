"""The closed-loop checks on the instrumented design (tvsd.analysis.instrument): whether a
command-side cause also passes the decision there (`instrumented_check`), whether a residual peak
of a least-squares fit is the plant's or the loop's answer to the noise (`peak_in_plant`), and the
note that a constant reference leaves the command maps untestable (`closed_loop_note`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tvsd.analysis import absorber, instrument, quantisation
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import Dataset
from tvsd.analysis.gls import gls
from tvsd.analysis.noise import COLOUR_P, NoiseReport, analyse, spectral_cause
from tvsd.analysis.rowgain import rows_gain
from tvsd.analysis.rules import DEFAULT, Rules

# The least-squares effect in the instrumented block's standard errors below which the
# confirmation cannot tell that effect from none: inside the instrumented estimate's 95 % interval
# around zero (two-sided normal quantile). The decision's gate (z ~3.8, a standardised likelihood
# ratio: a Wald statistic of ~3) is higher, so every refusal this calls powerless is one.
NO_POWER = 1.96


@dataclass
class Confirmation:
    """The instrumented confirmation: `holds(cause)` whether the cause passes the decision on the
    instrumented design; `power(cause, option, coef)` the least-squares block's coefficients
    `coef` in the instrumented block's standard errors (a Wald statistic, √(cᵀ V⁻¹ c)): what the
    confirmation could show of the effect least squares found (docs/measurements/closeddrift.md)."""

    holds: Callable[[str], bool]
    power: Callable[[str, D.Option, np.ndarray], float]

    def __call__(self, cause: str) -> bool:
        return self.holds(cause)


def instrumented_check(
    prep: Any, data: Dataset, rotary: bool, measured: D.Design, seed: int, rules: Rules = DEFAULT
) -> Confirmation | None:
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
    memo: dict[tuple[bool, bool, bool], tuple[D.Design, C.Outcome]] = {}

    def decided(cause: str) -> tuple[D.Design, C.Outcome]:
        # Per cause (rules.identified_for, expected_for; docs/measurements/closedsat.md): the
        # clip's block as E[f(u) | instruments], θ_IV along identified directions only.
        key = (
            cause in rules.identified_for or rules.identified_only,
            cause in rules.expected_for or rules.expected_maps,
            cause in rules.spin_only_for,
        )
        if key not in memo:
            ident, expect, spin = key
            iv, _ = instrument.instrumented(
                prep, data.offset_term, rotary, expected=expect, spin_only=spin, rules=rules
            )
            iv = absorber.absorb(iv)
            iv.back_emf = measured.back_emf
            iv.y = instrument.structural_left_side(iv, measured, identified_only=ident)
            memo[key] = (iv, C.test_all(iv, seed=seed))
        return memo[key]

    def holds(cause: str) -> bool:
        out = decided(cause)[1]
        return any(t.cause == cause and t.z > out.threshold for t in out.tested)

    def power(cause: str, option: D.Option, coef: np.ndarray) -> float:
        iv, out = decided(cause)
        same = [o for o in iv.options.get(cause, []) if o.effect == option.effect]
        if not same or len(coef) != same[0].block.shape[1]:
            return math.inf  # nothing to compare: not called powerless
        k = same[0].block.shape[1]
        fit = gls(iv.y, np.column_stack([iv.X, same[0].block]), out.ar, out.keep)
        cov = fit.cov[-k:, -k:]
        c = np.asarray(coef, dtype=float)
        if not np.all(np.isfinite(cov)):
            return math.inf
        try:
            return math.sqrt(max(float(c @ np.linalg.solve(cov, c)), 0.0))
        except np.linalg.LinAlgError:
            return math.inf

    return Confirmation(holds, power)


LOOP_PEAK = (
    "loop_peak",
    "closed loop: the residual's peak is not in the residual of the instrumented fit (the reference "
    "as instrument), so it is the loop's answer to the noise that least squares on the measured "
    "command leaves, not a mode of the plant",
)


def plant_noise(
    prep: Any,
    data: Dataset,
    rotary: bool,
    measured: D.Design,
    keep: np.ndarray,
    rules: Rules = DEFAULT,
    identified_only: bool = False,
) -> NoiseReport | None:
    """The spectral tests on the instrumented fit's residual y − X·θ_IV (the measured columns,
    θ_IV from the reference and identify's PRBS): the equation's own error — the vibration and
    the speed-measurement noise — which the law's answer to the noise does not shape, unlike the
    least-squares residual on the measured command. None without an excitation to instrument
    with (a constant reference)."""
    if not instrument.excited(data):
        return None
    iv, _ = instrument.instrumented(prep, data.offset_term, rotary, expected=rules.expected_maps, rules=rules)
    resid = instrument.structural_residual(absorber.absorb(iv), measured, identified_only)
    if resid is None:
        return None
    rate = 1.0 / float(np.median(np.diff(prep.t_rows)))
    gated, floor = quantisation.gated(prep, keep, resid, rate)
    return analyse(gated, rate, 1.0, prep.band.cutoff_hz, floor, rows_gain(prep))


def peak_in_plant(noise: NoiseReport, plant: NoiseReport | None) -> bool:
    """Whether a residual peak of a closed-loop least-squares fit is the plant's: the law feeds
    the measured noise back into the command, so least squares on that command is biased and its
    residual keeps a share of the loop's answer to the noise — S = 1/(1 + PC) shaped, peaked at
    the loop's own mode when it is underdamped (an outsider PI loop's 10.6 Hz on a null,
    docs/measurements/loopmode.md). The instrumented fit's residual (`plant`: plant_noise) is the
    equation's own error: a mode of the plant is a torque in it and stays; the bias, and with it
    the loop's peak, goes. The peak must be there too, within its half-power band."""
    if plant is None or spectral_cause(plant, COLOUR_P) != "resonance":
        return False  # nothing to instrument with: a peak is not told from the loop's
    df = float(noise.freq[1] - noise.freq[0]) if len(noise.freq) > 1 else 0.0
    half = max(noise.peak_hz / (2.0 * noise.peak_q), df) if noise.peak_q > 0 else df
    return abs(plant.peak_hz - noise.peak_hz) <= half


def closed_loop_note(data: Dataset) -> str | None:
    if not data.closed_loop or instrument.reference_moves(data):
        return None
    return (
        "closed loop with a constant reference: dead zone, saturation and delay are not testable "
        "(the command answers the noise); record with reference steps (tvsctl identify)"
    )
