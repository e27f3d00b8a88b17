"""One definition of closed loop (Dataset.closed_loop, Dataset.speed_reference): a recording that
holds the controller's position reference alone (`phi_ref`; DESIGN.md's recording CSV allows
either reference) is a closed loop as one with `omega_ref` is. A position loop's command is a
function of the measured angle, so it answers the noise: least squares on it is biased and the
reference (its derivative, ω_ref = dφ_ref/dt) is the instrument. Before, the doctor, spectral_fit,
command_levels and instrument read such a file as open loop, speed_source and level_nuisance as
closed loop (docs/measurements/closedprop.md)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tvsd.analysis import closed_checks, command_levels, instrument, level_nuisance, matrix, speed_source
from tvsd.analysis.closed_plan import sized
from tvsd.analysis.dataset import ROTARY, Dataset, load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.matrix_open import heldout_gain_skipped
from tvsd.analysis.prep import Band
from tvsd.causes import parse_effect
from tvsd.config import Config, load_config
from tvsd.recording.csvfile import read, write
from tvsd.sim.record import record

FS = 1000.0


def _dataset(refs: dict[str, np.ndarray]) -> Dataset:
    """A 20 s voltage staircase (held levels) with the given reference columns."""
    t = np.arange(int(20 * FS)) / FS
    u = np.repeat([2.0, -3.0, 4.0, -1.0, 3.0], len(t) // 5)
    speed = 10.0 * u + 0.1 * np.random.default_rng(0).standard_normal(len(t))
    phi = np.cumsum(speed) / FS
    return Dataset("x.csv", t, u, phi, speed, FS, 1.0, 0.1, ROTARY, False, refs=refs)


def test_either_reference_makes_a_closed_loop_and_every_rule_asks_the_same() -> None:
    """phi_ref alone: closed loop, its speed reference dφ_ref/dt (exact on a ramp), moving when
    φ_ref does; held at one angle (a position hold) a constant reference, whose note drops the
    command maps. Neither reference (u_exc alone is no reference): open loop. The open-loop-only
    rules (the encoder swap, the bridge's levels in the null, the held levels of the colour test)
    stay off for both references."""
    t = np.arange(int(20 * FS)) / FS
    ramp = 2 * math.pi * (5.0 * t + 0.5 * np.sin(2 * math.pi * 0.5 * t))  # a moving position reference
    speed_ref = np.gradient(ramp, t)
    for refs in ({"phi_ref": ramp}, {"omega_ref": speed_ref}, {"omega_ref": speed_ref, "phi_ref": ramp}):
        d = _dataset(refs)
        assert d.closed_loop
        assert instrument.reference_moves(d) and closed_checks.closed_loop_note(d) is None
        assert level_nuisance.held(d, 5000) is None and speed_source.compared(d, Band()) is None
    only_phi = _dataset({"phi_ref": ramp})
    assert only_phi.speed_reference is not None
    np.testing.assert_allclose(only_phi.speed_reference, np.gradient(ramp, t))
    hold = _dataset({"phi_ref": np.full(len(t), 1.0)})
    assert hold.closed_loop and not instrument.reference_moves(hold)
    assert closed_checks.closed_loop_note(hold) is not None
    for refs in ({}, {"u_exc": np.ones(len(t))}):
        d = _dataset(refs)
        assert not d.closed_loop and d.speed_reference is None and not instrument.excited(d)
        assert closed_checks.closed_loop_note(d) is None
    # the held levels of a closed-loop command are the law's, not the drive's (colour test)
    assert command_levels.usable_levels(only_phi.u, only_phi.closed_loop, 5000) is None


def _phi_ref_only(src: Path, dst: Path) -> Path:
    """The recording without its omega_ref column: the controller's position reference alone."""
    rec = read(src)
    meta = {k: v for k, v in rec.meta.items() if k not in ("tvs-recording", "sample_rate_hz")}
    extra = {k: v for k, v in rec.extra.items() if k != "omega_ref"}
    write(dst, rec.t, rec.u, rec.omega, rec.phi, rec.sample_rate_hz, meta, extra)
    return dst


def _recorded(case: matrix.Case, tmp: Path) -> tuple[Path, Config]:
    """The matrix's closed-loop case as its run records it (identify profile, 30 s)."""
    cfg = matrix.case_config(load_config(), case)
    case = sized(case, cfg, tmp, 30.0)
    path = tmp / f"case{case.seed}.csv"
    effects = (parse_effect(case.effect),) if case.effect else ()
    record(cfg, path, case.profile, 30.0, effects, case.seed, rps=case.rps)
    return path, cfg


def _judged(path: Path, cfg: Config) -> tuple[str, dict[str, float]]:
    with heldout_gain_skipped():
        dg = diagnose(load(path, cfg), cfg.plant.v0)
    return dg.cause, {s.cause: float(s.z) for s in dg.ranked}


@pytest.mark.slow  # three 30 s closed-loop analyses, two SIL recordings: 8 s idle, ~60 s loaded
def test_a_phi_ref_only_recording_is_judged_as_the_closed_loop_it_is(tmp_path: Path) -> None:
    """Matrix null 910212 (seed 91's closed family) without its omega_ref: `delay` before (read
    as open loop, least squares on the law's answer to the noise), `none` now, as with omega_ref.
    Matrix case 3 (seed 0, a 15 ms delay, 30×) without its omega_ref: `delay`, with the z of the
    file with omega_ref — the SIL writes omega_ref = dφ_ref/dt, so the two instruments differ only
    by the CSV's 9 significant digits (1 % covers that rounding many times over)."""
    null = matrix.cases(n_null=213, reps=0, seed=91, profiles=matrix.CLOSED_PROFILES)[212]
    path, cfg = _recorded(null, tmp_path)
    cause, ranked = _judged(_phi_ref_only(path, tmp_path / "null-phi.csv"), cfg)
    assert cause == "none", ranked

    pool = matrix.cases(n_null=0, reps=1, seed=0, causes=("delay",), profiles=matrix.CLOSED_PROFILES)
    case = next(c for c in pool if c.size == 30.0)
    path, cfg = _recorded(case, tmp_path)
    with_omega = _judged(path, cfg)
    cause, ranked = _judged(_phi_ref_only(path, tmp_path / "delay-phi.csv"), cfg)
    assert with_omega[0] == cause == "delay", (with_omega, ranked)
    assert ranked["delay"] == pytest.approx(with_omega[1]["delay"], rel=0.01)
