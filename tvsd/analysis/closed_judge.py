"""How a closed-loop matrix case is judged (tvsd.analysis.matrix_closed runs them): by which
variant of the doctor, and what the recording exposes of the case's effect.

Variants: `ls` (least squares, the doctor's default), `iv` (two-stage least squares with the
reference and, when recorded, identify's voltage excitation `u_exc` as instruments),
`iv_ref` (the reference alone, as before u_exc was recorded), `ls0` (least squares as before
branch heldout: every fold in the out-of-sample check, crossval.heldout_gain; the line scan off the
command's lines), `ls1` (the folds' rule on, the lines still the command's), `ls2` (the
instrumented confirmation with rules.identified_only and expected_maps: branch cldz), `lsm`
(the clip confirmed on main's instrumented design, as before branch closedsat), `lsd` (the drift
confirmed along the identified directions too), `lss` (the clip's confirmation on rows from the
spin-up's end: instrument.steady_start's spin_only); both measured and left off
(docs/measurements/closedsat.md). `lscc`: the noise colour a closed-loop candidate by least squares with an
excited reference (measured, left off: SIL daemon exports show a colour their plant does not
have; docs/measurements/closedcolour.md). `lsdp` / `lsdp0`: a closed-loop drift whose
confirmation has no power for it stands on least squares, the trend test and the held-out folds
(rules.drift_ls_alone on / off; docs/measurements/closeddrift2.md). `lsap` / `lsap0`: the same for
a direction split whose windows agree on one level (rules.asym_ls_alone on / off;
docs/measurements/closed14.md). Each is a frozen `Variant`
(VARIANTS) whose rules (tvsd.analysis.rules) diagnose() gets explicitly. (`lscf`, the drift
confirmed with a control function, was measured and removed: docs/measurements/closedfix.md.)
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.analysis import matrix as M
from tvsd.analysis.rules import DEFAULT, Rules
from tvsd.config import Config


@dataclasses.dataclass(frozen=True)
class Variant:
    """One way of running the doctor on the matrix's files: its rules, 2SLS as the whole
    analysis (`iv`), and whether identify's PRBS column is hidden from it (the reference alone)."""

    rules: Rules = DEFAULT
    iv: bool = False
    reference_only: bool = False


VARIANTS: dict[str, Variant] = {
    "ls": Variant(),
    "lsm": Variant(Rules(identified_for=(), expected_for=(), spin_only_for=())),
    "lsd": Variant(Rules(identified_for=(*DEFAULT.identified_for, "drift"))),
    "lss": Variant(Rules(spin_only_for=("saturation",))),
    "ls0": Variant(Rules(skip_undetermined_folds=False, lines_of_reference=False)),
    "ls1": Variant(Rules(lines_of_reference=False)),
    "ls2": Variant(Rules(identified_only=True, expected_maps=True)),
    "lscc": Variant(Rules(closed_colour=True)),
    "lsdp": Variant(Rules(drift_ls_alone=True)),
    "lsdp0": Variant(Rules(drift_ls_alone=False)),
    "lsap": Variant(Rules(asym_ls_alone=True)),
    "lsap0": Variant(Rules(asym_ls_alone=False)),
    "iv": Variant(iv=True),
    "iv_ref": Variant(iv=True, reference_only=True),
}


def analyse(path: Path, cfg: Config, variant: str) -> tuple[str, float, dict[str, Any]]:
    """What the variant named, its time, and why (each cause's z, the threshold, a mismatch's
    reason): the confusion table's raw material."""
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose

    t0 = time.perf_counter()
    why: dict[str, Any] = {}
    how = VARIANTS[variant]
    try:
        data = load(path, cfg)
        if how.reference_only:
            data = dataclasses.replace(data, refs={k: v for k, v in data.refs.items() if k != "u_exc"})
        dg = diagnose(data, cfg.plant.v0, iv=how.iv, rules=how.rules)
        found = dg.cause
        why = {
            "z": {s.cause: round(float(s.z), 3) for s in dg.ranked},
            "threshold": round(float(dg.outcome.threshold), 3),
            "reason": dg.reason,
            # which check refused a cause (verdict.WHY's codes): the gate, a refit, the instruments
            "why_not": {s.cause: s.why_not[0] for s in dg.ranked if s.why_not},
        }
    except Exception as exc:  # a bad case is a result too (reported, not hidden)
        found = f"error: {type(exc).__name__}: {exc}"[:160]
    return found, time.perf_counter() - t0, why


# The causes whose closed-loop answer is decided by their instrumented confirmation
# (closed_checks.instrumented_check): their size is measured on its rows and columns.
CONFIRMED_SIZES = ("saturation", "deadzone", "drift")


def seen(path: Path, case: M.Case, cfg: Config) -> dict[str, float]:
    """tvsd.analysis.exposure's measures of the case's effect on the recording the doctor got; a
    clip's and a dead zone's exposed units and a drift's visible units on the rows and columns of
    its confirmation (the default rules'; branch closedfix for the clip, closedrules the others).
    """
    from tvsd.analysis.dataset import load
    from tvsd.analysis.exposure import confirmation_baseline, exposure

    data = load(path, cfg)
    omega = data.speed if data.speed is not None else np.gradient(data.position, data.t)
    dt = 1.0 / data.sample_rate_hz
    baseline = confirmation_baseline(data, case.cause) if case.cause in CONFIRMED_SIZES else None
    return exposure(case.effect, data.u, omega, cfg.plant, case.sigma_v, dt, baseline)
