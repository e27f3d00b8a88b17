"""The doctor's switchable rules, one frozen value passed down explicitly (diagnose(rules=...)).

The closed-loop matrix (tvsd.analysis.matrix_closed) judges the same recordings by several
variants of the doctor: the rule before a change, and changes measured but left off. These were
module-level flags that the matrix (and scripts, and tests) set and put back around each
analysis, which leaked into any later caller if it did not. Here they are one immutable value:
`diagnose` gives it to the design it builds (tvsd.analysis.design.build(rules=...), also the
instrumented designs of tvsd.analysis.instrument), where the out-of-sample check
(tvsd.analysis.crossval), the line scan (tvsd.analysis.linescan), the drift's windows
(tvsd.analysis.drift) and the instrumented confirmation (tvsd.analysis.closed_checks) read it.
A rule before a change is `dataclasses.replace(DEFAULT, field=...)`. DEFAULT is the doctor's rule.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Rules:
    # crossval.heldout_gain: leave out the folds the others do not determine (False: every fold,
    # the rule before; matrix_closed's `ls0`)
    skip_undetermined_folds: bool = True
    # ... and the folds the others do not pin down (fold leverage ≥ the record's evidence; False:
    # every fold of full rank judged, the rule before branch heldout; scripts/null_confirmations)
    skip_unpinned_folds: bool = True
    # drift.confirmed: the windows' trend test (False: the per-window refits it replaced,
    # scripts/drift_rejudge.py); in those refits, windows that cannot resolve the drift's whole
    # change left out (False: every window counted, as before)
    drift_trend_test: bool = True
    drift_pinned_windows: bool = True
    # calibrate's line scan: in closed loop the reference's lines, not the command's (`ls0`, `ls1`)
    lines_of_reference: bool = True
    # Every command-side cause's confirmation with θ_IV along identified directions only and the
    # maps' blocks as E[f(u) | instruments] (branch cldz's `ls2`; docs/measurements/cldz.md)
    identified_only: bool = False
    expected_maps: bool = False
    # Per cause (closed_checks.instrumented_check; docs/measurements/closedsat.md): the clip's
    # confirmation along identified directions, its block as E[f(u) | instruments]; rows from the
    # spin-up's end (instrument.steady_start's spin_only) for none by default
    identified_for: tuple[str, ...] = ("saturation",)
    expected_for: tuple[str, ...] = ("saturation",)
    spin_only_for: tuple[str, ...] = ()
    # doctor.py: the noise colour a candidate in closed loop by least squares with an excited
    # reference and identify's excitation (u_exc; matrix_closed's `lscc`). On since the exports
    # declare their encoder frames and the doctor has the interpolated angle's quantisation floor:
    # SIL daemon identify null exports and the offline closed nulls stay under the gate
    # (docs/measurements/closedcolour2.md); before, a τ 3–10 ms colour above the gate on 4 of 18
    # exports (docs/measurements/closedcolour.md)
    closed_colour: bool = True
    # ... and only where identify's excitation (u_exc) played; False: with any moving reference
    # (the rule before closedcolour2's narrowing), measured in docs/measurements/closedcolour3.md
    closed_colour_u_exc: bool = True
    # verdict.name_cause: in closed loop, a drift whose instrumented confirmation has no power
    # for it (closed_checks.NO_POWER) stands on least squares alone when its windows' trend is a
    # clean line (drift.ls_alone: t at the decision's 1 %, no step, no excess scatter); the gate,
    # the trend test and the held-out folds are passed before. False: refused, the rule before
    # (matrix_closed's `lsdp0`; 0 alarms added on 450 closed nulls, o12114/o13115 named:
    # docs/measurements/closeddrift2.md)
    drift_ls_alone: bool = True
    # ... and a friction asymmetry (the direction split) when the negative direction's visits in
    # separate time windows agree on one split (asymmetry.ls_alone: ≥ 4 windows, no excess
    # scatter, the level's t at the decision's 1 %). False: refused, the rule before
    # (matrix_closed's `lsap0`; docs/measurements/closed14.md)
    asym_ls_alone: bool = True
    # drift.confirmed: where no instrumented confirmation follows (open loop; closed loop without an
    # excited reference, or by 2SLS), the windows' slope
    # at the decision's α/3 (t > 4.12 at 8 df), not the trend test's 5 %/3 (3.02). False: the
    # rule before (outsider null o14042 named drift, t −3.55; docs/measurements/drift14.md)
    drift_alone_alpha: bool = True


DEFAULT = Rules()
