"""The noise colour in closed loop by least squares (issue 12; docs/measurements/closedcolour.md).

With an excited reference (identify's steps, multisine, PRBS) the least-squares residual's colour
is judged when `rules.closed_colour` is on (matrix_closed's `lscc`): on the offline closed-loop
matrix its nulls stay under the test's χ² level and a 15 ms colour is named. It is on by default
since SIL daemon identify exports of a white plant, with their interpolated angle's quantisation
floor, stay under the gate too (docs/measurements/closedcolour2.md; without that floor a low-pass
residual of τ 7–10 ms above the gate on 4 of 18 files)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tvsd.analysis import doctor
from tvsd.analysis.closed_plan import case_config, plan_cells
from tvsd.analysis.dataset import Dataset, load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.noise import NoiseReport
from tvsd.analysis.rules import DEFAULT
from tvsd.causes import parse_effect
from tvsd.config import Config
from tvsd.sim.record import record

CASE = 710119  # closed-loop matrix seed 71: colored_noise 30× (τ 15 ms), σv 0.34, 10 rev/s
TAU_S = 0.015


@pytest.fixture(scope="module")
def coloured(tmp_path_factory: pytest.TempPathFactory) -> tuple[Dataset, Config]:
    case = next(c for c in plan_cells(8, (3.0, 10.0, 30.0), 71, 4) if c.seed == CASE)
    assert case.cause == "colored_noise" and case.size == 30.0
    cfg = case_config(case)
    path = tmp_path_factory.mktemp("closedcolour") / "case.csv"
    assert case.effect is not None
    record(cfg, path, "identify", 30.0, (parse_effect(case.effect),), case.seed, rps=case.rps)
    return load(path, cfg), cfg


@pytest.mark.slow
def test_a_closed_loop_colour_is_named_with_the_rule_and_refused_without(
    coloured: tuple[Dataset, Config],
) -> None:
    """Without the rule: `none`, the colour refused as `closed_loop_colour` (likelihood ratio 835
    on this file). With it (the default): `colored_noise`. Its τ within a factor 2 of the plant's 15 ms: least
    squares on the measured command takes the noise's share the law answers (below the loop's
    band) out of the residual, which flattens the low end of the spectrum, so the fitted corner
    moves; a factor 2 keeps the corner (11 Hz) inside 5.3–21 Hz, well inside the 0.5–50 Hz band
    the test sees, and tells it from the daemon exports' 7–10 ms above the gate (module doc)."""
    data, cfg = coloured
    on = diagnose(data, cfg.plant.v0)
    assert on.cause == "colored_noise", [(s.cause, s.z, s.why_not) for s in on.ranked]
    assert TAU_S / 2 < on.effect["tau_s"] < 2 * TAU_S, on.effect
    off = diagnose(data, cfg.plant.v0, rules=dataclasses.replace(DEFAULT, closed_colour=False))
    assert off.cause == "none"
    colour = next(s for s in off.ranked if s.cause == "colored_noise")
    assert colour.p < 1e-3 and colour.why_not is not None and colour.why_not[0] == "closed_loop_colour"


def test_a_colour_under_the_loops_own_peak_is_refused_as_the_loops() -> None:
    """A colour that passes its test while the residual's peak is the loop's (closed_checks'
    loop_peak) is not named: the spectrum's shape there is the loop's answer to the noise."""
    f = np.linspace(0.0, 125.0, 501)
    report = NoiseReport(0.5, 30.0, 1e-7, 0.01, 0.3, f, np.ones_like(f))
    why = doctor._colour_why(report, "none", closed=False, peak=False, loop_peak=True)
    assert why is not None and why[0] == "loop_shaped"
    assert (
        doctor._colour_why(report, "none", closed=True, peak=False, loop_peak=True)[0] == "closed_loop_colour"
    )  # type: ignore[index]
    assert doctor._colour_why(report, "colored_noise", closed=False, peak=False, loop_peak=False) is None


def test_the_variants_switch_the_closed_loop_colour() -> None:
    from tvsd.analysis.closed_judge import VARIANTS

    assert DEFAULT.closed_colour  # on by default (docs/measurements/closedcolour2.md)
    assert VARIANTS["lscc"].rules == dataclasses.replace(DEFAULT, closed_colour=True)
