"""The doctor's switchable rules, one frozen value passed down explicitly (diagnose(rules=...)).

The closed-loop matrix (tvsd.analysis.matrix_closed) judges the same recordings by several
variants of the doctor: the rule before a change, and changes measured but left off. These were
module-level flags that the matrix set and put back around each analysis, which leaked into any
later caller if it did not. Here they are one immutable value: `diagnose` puts it on the design
(tvsd.analysis.design.Design.rules), where the out-of-sample check and the line scan
(tvsd.analysis.calibrate) and the instrumented confirmation (tvsd.analysis.doctor,
tvsd.analysis.instrument) read it. DEFAULT is the doctor's rule.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Rules:
    # crossval.heldout_gain: leave out the folds the others do not determine (False: every fold,
    # the rule before; matrix_closed's `ls0`)
    skip_undetermined_folds: bool = True
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


DEFAULT = Rules()
