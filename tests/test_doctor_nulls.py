"""Null recordings of the randomised matrix are called `none` (issue 12, item 5: ≤ 2 % false alarms).

Open loop: ten seeded nulls of tvsd.analysis.matrix (seed 1, nulls 17–26: plants drawn over
÷√10…×√10 of the config's J, kv, τc, R, kM; staircase and PRBS/multisine; all three σv), 30 s at
1 kHz each, as `tvsctl bench --only doctor` runs them. Tolerance, from the target: if the
doctor's false-alarm rate is 2 %, ten independent nulls give 3 or more alarms with probability
1 − Σ_{k≤2} C(10,k)·0.02^k·0.98^(10−k) = 8.6e-4 < 1e-3, so at most 2 alarms may fail only by a
1-in-1000 chance. The rule before the input gain's covariance (its standard error from the two
input columns' separate errors) gave 4 alarms on these ten (`model_mismatch`, "the command
barely moves the shaft").

Closed loop: seven seeded nulls of the matrix's closed family (scanning with `tvsctl identify`'s
excitation; seed 2, nulls 9–15). At a 2 % rate seven nulls give 2 or more alarms with probability
1 − 0.98^7 − 7·0.02·0.98^6 = 7.9e-3, so at most 1. The rule before the misfit work (a resonance
scan against a flat spectrum, over the command's own lines; the noise colour tested in closed
loop) gave 4 of these seven: `resonance` at 7.99 Hz (the identify multisine's top line) twice
and at 79.6 Hz, `colored_noise` once. These seeds were among those the rule was diagnosed on
(docs/measurements/doctor-false-alarms.md, "False alarms"): a regression test, not the figure. With the null
drawn from the
residual's own spectrum and the threshold the empirical 99 % point of 2000 draws (calibrate.py)
the seventeen give 0 alarms (the largest standardised statistic 2.0 open, 6.3 closed: a delay
the refit dissolves); the tolerances stay those of the 2 % target.
"""

from __future__ import annotations

import pytest

from tvsd.analysis import matrix

pytestmark = pytest.mark.slow


def _alarms(cases, tmp_path) -> dict[int, str]:
    found = {c.seed: matrix.run_case(c, 30.0, tmp_path)["found"] for c in cases}
    return {k: v for k, v in found.items() if v != "none"}


def test_seeded_matrix_nulls_are_none(tmp_path):
    seed, first, count, max_alarms = 1, 17, 10, 2
    cases = matrix.cases(n_null=first + count, reps=0, seed=seed)[first:]
    assert len(cases) == count and all(c.cause == "none" for c in cases)
    alarms = _alarms(cases, tmp_path)
    assert len(alarms) <= max_alarms, f"false alarms on {len(alarms)} of {count} nulls: {alarms}"


def test_seeded_closed_loop_nulls_are_none(tmp_path):
    seed, first, count, max_alarms = 2, 9, 7, 1
    cases = matrix.cases(n_null=first + count, reps=0, seed=seed, profiles=matrix.CLOSED_PROFILES)[first:]
    assert len(cases) == count and all(c.cause == "none" and c.profile == "identify" for c in cases)
    alarms = _alarms(cases, tmp_path)
    assert len(alarms) <= max_alarms, f"false alarms on {len(alarms)} of {count} closed-loop nulls: {alarms}"


@pytest.mark.parametrize(
    ("seed", "index", "cause"),
    [(32, 59, "saturation"), (32, 89, "deadzone"), (52, 158, "saturation"), (52, 128, "delay")],
)
def test_closed_loop_nulls_the_feedback_made_alarms_are_not_named(tmp_path, seed, index, cause):
    """Closed-loop nulls of the matrix (`identify` excitation, σv 0.8069) that were named a
    cause: the law's answer to the noise makes the command correlate with the equation's error,
    which the bootstrap (conditioning on the regressors) does not represent.

    Seed 32, 59 and 89: a clip (z 6.5) and a dead zone (z 10.1) whose structural refits fitted
    worse than the recorded command (LR −55 and −6.5 noise variances; refit.structural_lr).
    Seed 52, 158: a clip at z 25.1 whose refit fitted (LR 12) but which the instrumented design
    puts at z 0.8 (closed_checks.instrumented_check). Seed 52, 128: `model_mismatch`, "negative
    Coulomb friction" at 3+ standard errors — the feedback's bias, not in the errors (a delay at
    z 11.2 that dissolves tops it). Each case is checked to still put `cause` above the gate,
    else the test would pass without exercising the rule; no tolerance: the run is seeded.

    Asserted: `cause` is not named, neither as the answer nor among the causes. Not that the
    answer is `none`: whether a null draws some other alarm is a matter of the false-alarm rate,
    judged on randomised nulls (the two tests above; 7/1200 closed nulls in
    docs/measurements/session6.md), not on one file. Seed 52, 128 is named `colored_noise`
    since the closed-loop colour is on (Rules.closed_colour, closedcolour2.md: likelihood ratio
    14.8 at τ 6 ms, σv 0.81, 10 rev/s), one of that rule's measured false alarms; this test
    expected it as the answer until memflake.md, so it would have failed when the colour's false
    alarm went away."""
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.config import load_config
    from tvsd.sim.record import record

    case = matrix.cases(n_null=index + 1, reps=0, seed=seed, profiles=matrix.CLOSED_PROFILES)[index]
    assert case.cause == "none" and case.profile == "identify"
    cfg = matrix.case_config(load_config(), case)
    path = tmp_path / "null.csv"
    record(cfg, path, case.profile, 30.0, (), case.seed, rps=case.rps or 20.0)
    dg = diagnose(load(path, cfg), cfg.plant.v0)
    top = dg.outcome.tested[0]
    assert top.cause == cause and top.z > dg.outcome.threshold, (top.cause, top.z, dg.outcome.threshold)
    named = [c.cause for c in dg.causes]
    assert dg.cause != cause and cause not in named, (dg.cause, named, dg.effect)
