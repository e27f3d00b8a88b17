"""Per-cause refits of the model doctor on seeded cases of the randomised matrix (issue 12, item 5).

Cases come from tvsd.analysis.matrix (a random plant over ÷√10…×√10 of the config's, the
matrix's own excitation and vibration level), seed 3, which no refit was tuned on.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from tvsd.analysis import matrix as M
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import Diagnosis, diagnose
from tvsd.causes import parse_effect
from tvsd.config import load_config
from tvsd.sim.record import record

pytestmark = pytest.mark.slow


def _diagnose(case: M.Case, tmp: Path) -> Diagnosis:
    """What matrix.run_case does, keeping the diagnosis (run_case keeps only the name)."""
    cfg = load_config()
    plant = dataclasses.replace(cfg.plant, **case.plant)  # type: ignore[arg-type]
    plant = dataclasses.replace(plant, kb=plant.kM * cfg.plant.kb / cfg.plant.kM)
    sil = cfg.sil_or_default
    vib = dataclasses.replace(sil.vibration, sigma_v=case.sigma_v)
    cfg = dataclasses.replace(cfg, plant=plant, sil=dataclasses.replace(sil, vibration=vib))
    path = tmp / f"case{case.seed}.csv"
    assert case.effect is not None
    record(cfg, path, case.profile, 30.0, (parse_effect(case.effect),), case.seed)
    return diagnose(load(path, cfg), cfg.plant.v0)


@pytest.mark.parametrize("size", [3.0, 10.0])
def test_a_dead_zone_narrower_than_every_command_level_is_measured(tmp_path, monkeypatch, size):
    """Staircase cases whose dead zone (0.14 V, 0.48 V) lies below the smallest command level:
    the width is seen only at reversals, where it and Coulomb friction push opposite ways. The
    old refit could not go below the smallest level and returned it (≈ 0.8 V for both).

    Tolerance: the width within the full width of its own 95 % profile-likelihood interval
    (≈ 4 standard errors; chance of a miss ≈ 1e-4), and the truth inside that interval
    widened by one grid step on each side (as reported: the chance it misses is 5 %, and the
    seeded case is fixed, so this checks the interval is not off by construction)."""
    monkeypatch.setattr(M, "SIZES", (size,))
    (case,) = M.cases(n_null=0, reps=1, seed=3, causes=("deadzone",))
    assert case.profile == "steps"
    dg = _diagnose(case, tmp_path)
    assert dg.cause == "deadzone", f"{case.effect}: found {dg.cause} {dg.effect}"
    true = float(case.effect.split("=")[1]) if case.effect else 0.0
    lo, hi = dg.effect["u0_interval"]
    assert abs(float(dg.effect["u0"]) - true) <= hi - lo, (dg.effect, true)
    assert lo <= true <= hi, (dg.effect, true)


@pytest.mark.parametrize("size", [3.0, 30.0])
def test_a_delay_is_measured_to_a_fraction_of_a_sample(tmp_path, monkeypatch, size):
    """Delays of 1.5 and 15 ms at 1 kHz: the grid of whole samples alone is ±1 sample; the input
    columns' weights give the fraction (u delayed by k − a₁/(a₀+a₁) samples, first order in the
    100 Hz band). Errors measured on 16 cases of other seeds and bench-dev: ≤ 0.2 samples; the
    tolerance, half a sample, is what the grid alone could not meet."""
    monkeypatch.setattr(M, "SIZES", (size,))
    (case,) = M.cases(n_null=0, reps=1, seed=3, causes=("delay",))
    dg = _diagnose(case, tmp_path)
    assert dg.cause == "delay", f"{case.effect}: found {dg.cause} {dg.effect}"
    true = float(case.effect.split("=")[1]) if case.effect else 0.0
    assert abs(float(dg.effect["delay_s"]) - true) <= 0.5e-3, (dg.effect, true, case.profile)
