"""The drift's windowed trend test (tvsd.analysis.drift): a trend, not any windowed disagreement."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tvsd.analysis import drift
from tvsd.analysis import matrix as M
from tvsd.analysis.matrix_open import plan
from tvsd.analysis.rules import DEFAULT

K = 10
X = (np.arange(K) + 0.5) / K  # window centres, share of the record


def _cov(se: float, common: float = 0.0) -> np.ndarray:
    """Independent window errors `se` plus a level `common` all windows share (the baseline's)."""
    return np.eye(K) * se**2 + common**2


def test_a_line_through_windows_that_share_an_uncertain_level_is_a_trend():
    """A change of 0.006 over the record, windows each ±0.001 about the line, and a level they all
    share known to ±0.01 only (7× the change: seed 710021's windows). The slope's error comes from
    the differences, so t ≈ 0.006 / (0.001/√(K·var x)) ≈ 5.4 > t(8) at 0.05/3 (3.0); the opposite
    sign, or no change, is no trend."""
    noise = np.random.default_rng(1).normal(0.0, 0.001, K)
    y = 0.3 + 0.006 * X + noise + 0.02
    tr = drift.trend(X, y, _cov(0.001, 0.01), sign=0.006)
    assert tr.agrees and tr.t > 4 and tr.df == K - 2
    assert not drift.trend(X, y, _cov(0.001, 0.01), sign=-0.006).agrees
    assert not drift.trend(X, 0.3 + noise, _cov(0.001, 0.01), sign=0.006).agrees


def test_windows_that_scatter_beyond_their_errors_set_the_bar():
    """A weak slope (0.004 over the record) among windows scattering ±0.01 where each claims ±0.001
    (misfit, coloured noise: overdispersion φ ≈ 100): judged on the stated errors it would be a
    trend (t ≈ 4), judged on the scatter it is not (t ≈ 0.4)."""
    rng = np.random.default_rng(2)
    y = 1.0 + 0.004 * X + rng.normal(0.0, 0.01, K)
    tr = drift.trend(X, y, _cov(0.001), sign=0.004)
    assert tr.phi > 20 and not tr.agrees


def test_a_step_is_not_a_drift():
    """A step of 0.05 between windows 5 and 6, windows ±0.005: a line through it has t ≈ 5, but
    the two levels fit far better than the line (F ≫ F(1, 8) 95 % = 5.3). The same rise as a line
    passes."""
    rng = np.random.default_rng(3)
    noise = rng.normal(0.0, 0.005, K)
    step = np.where(np.arange(K) < 5, 0.0, 0.05) + noise
    tr = drift.trend(X, step, _cov(0.005), sign=0.05)
    assert abs(tr.t) > tr.t_crit and tr.step_f > tr.f_crit and not tr.agrees
    line = 0.05 * X + noise
    assert drift.trend(X, line, _cov(0.005), sign=0.05).agrees


def test_windows_that_cannot_resolve_the_change_are_left_out_and_too_few_is_no_trend():
    """A window whose error against the others is at least the whole change is left out (it
    cannot show the trend); with fewer than MIN_WINDOWS left the drift is not confirmed."""
    cov = _cov(0.001)
    cov[0, 0] = 1.0**2  # window 0: ±1 where the change is 0.01
    y = 0.01 * X
    y[0] = -5.0
    tr = drift.trend(X, y, cov, sign=0.01)
    assert len(tr.est) == K - 1 and tr.agrees
    few = drift.trend(X[:3], y[1:4], _cov(0.001)[:3, :3], sign=0.01)
    assert not few.agrees


@pytest.mark.slow
@pytest.mark.parametrize(
    ("seed", "plan_seed", "sizes", "thin"),
    [(310028, 31, (1.0, 3.0, 10.0, 30.0), (1.0,)), (330051, 33, (3.0, 10.0, 30.0), ())],
)
def test_matrix_drifts_the_per_window_refits_refused_are_named(tmp_path, seed, plan_seed, sizes, thin):
    """Refused before by the per-window refits (drift.window_refits_agree: every baseline coefficient
    refitted per 6 s window, an unweighted line through five): 310028, a 0.5 % kv drift at z 6.0
    (staircase), windows −1.8027 … −1.8102 ± 0.002 with the last one back up; 330051, a 15 %
    friction drift at z 53 (staircase), windows −8.55, −8.47, −8.78, −8.57, −8.95 — both t < 2.
    Split by window with the rest shared, the windows fall steadily: t −4.7 (df 6) and −15.4
    (df 8), against Student's t at 0.05/3 of 3.3 and 3.0, no step fitting better. Open-loop plan
    seeds 31/33 (tvsd.analysis.matrix_open). Deterministic (seeded recording and bootstrap)."""
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.sim.record import record

    case = next(c for c in plan(2, sizes, plan_seed, thin=thin) if c.seed == seed)
    assert case.cause == "drift"
    cfg = M.case_config(load_config(), case)
    path = tmp_path / "case.csv"
    assert case.effect is not None
    record(cfg, path, case.profile, 30.0, (parse_effect(case.effect),), case.seed)
    data = load(path, cfg)
    assert diagnose(data, cfg.plant.v0).cause == "drift"
    before = dataclasses.replace(DEFAULT, drift_trend_test=False)
    assert diagnose(data, cfg.plant.v0, rules=before).cause == "none"  # the rule before


def test_an_r_drift_at_a_steady_speed_is_visible_only_as_the_friction_it_balances():
    """At a steady speed the drive's torque beyond the back-EMF, b_u·u − b_ω·ω, is what the
    friction takes (kv·ω + τc), and an R drift scales just that: 15 % of it over the record is
    Δ·(kv·ω + τc)·rms(t/T − ½) = 0.15·(1e-4·100 + 2e-3)/√12 ≈ 5.2e-4 N·m, where the table's
    units (Δ·b_u·rms u) say 0.15·0.262 ≈ 0.039 N·m (the back-EMF takes 0.25). Noise units: over J·σv."""
    from types import SimpleNamespace

    from tvsd.analysis.exposure import exposure

    plant = SimpleNamespace(J=1e-4, kv=1e-4, R=1.0, kM=0.05, ku=1.0, kb=0.05, tau_c=2e-3)
    b_u, b_w = plant.kM * plant.ku / plant.R, plant.kM * plant.kb / plant.R
    w = np.full(30_000, 100.0)
    u = np.full_like(w, (plant.kv * 100.0 + plant.tau_c + b_w * 100.0) / b_u)
    e = exposure("drift:parameter=R,relative_change=0.15", u, w, plant, 1.0, 1e-3)
    expect = 0.15 * (plant.kv * 100.0 + plant.tau_c) / np.sqrt(12) / plant.J
    assert e["visible"] == pytest.approx(expect, rel=0.01)
    assert (
        e["units"] == pytest.approx(0.15 * b_u * u[0] / plant.J, rel=1e-3) and e["units"] > 10 * e["visible"]
    )
    # a shaft that never moves shows no drift of its friction
    still = exposure("drift:parameter=friction,relative_change=0.15", u, np.zeros_like(w), plant, 1.0, 1e-3)
    assert still["visible"] == 0.0
