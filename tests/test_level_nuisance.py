"""A voltage or duty command held on levels, read through the encoder: a bridge's per-level error
is the null's, not a cause (tvsd.analysis.level_nuisance; docs/measurements/pwmlevel.md).

An 8-bit bridge applies each held level with its own constant error (up to half a PWM step, 0.5 %
of the top command on the outsider bench). Through a noisy tach it was hidden; through the
encoder's count difference it was named as a clip, a drift or a friction asymmetry on 3 of 14
outsider nulls, so such commands kept the tach (outsidereff.md) and lost the effects the encoder
shows (a 20× delay on a voltage staircase: z 1.45 through the tach, 167 through the encoder)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import outsider_bench as ob
import pytest

from tvsd.analysis import doctor, level_nuisance, speed_source
from tvsd.analysis.dataset import load
from tvsd.config import load_config

TVSCTL = str(Path(sys.executable).parent / "tvsctl")


def test_the_levels_scatter_is_read_past_a_few_outlying_levels() -> None:
    """null_term's τ² (ratio × the noise's σ² = 0.01): 40 levels of 200 rows, each with a uniform
    ±1 error (variance 1/3; the MAD reads a uniform's σ 1.28× wide, 0.55, capped by the levels'
    mean square, 0.33) and white noise of 0.1, is read within 0.5–2× of 0.55 (the MAD of 40 values:
    ~25 % s.e. in σ, ±50 % in σ² at 2 s.e.);
    with a clip-like error of 30 on 4 of the levels it is read about as wide (the median ignores
    them; a mean square reads ~90). Without scatter the bridge's bound holds: gain² h²/3."""
    rng = np.random.default_rng(3)
    k, m = 40, 200
    C = np.kron(np.eye(k), np.ones((m, 1)))
    Q0 = np.ones((k * m, 1)) / np.sqrt(k * m)  # the baseline: a constant
    keep = np.ones(k * m, dtype=bool)
    a = np.array([1.0])
    delta = rng.uniform(-1, 1, k)
    noise = 0.1 * rng.standard_normal(k * m)
    for bump in (np.zeros(k), np.r_[np.full(4, 30.0), np.zeros(k - 4)]):
        e = C @ (delta + bump) + noise
        e0 = e - Q0 @ (Q0.T @ e)
        null = level_nuisance.null_term(level_nuisance.Levels(C, 1e-9), 1.0, a, keep, Q0, e0, 1)
        assert 0.5 * 0.55 < null.ratio(e0) * 0.01 < 2 * 0.55
    # a cause that moves every level (a drift: a trend of 10 over them) is judged with it fitted:
    # with the trend in the model the scatter left is the ±1 errors' again
    trend = C @ np.linspace(-10, 10, k)
    e = C @ delta + trend + noise
    e0 = e - Q0 @ (Q0.T @ e)
    null = level_nuisance.null_term(level_nuisance.Levels(C, 1e-9), 1.0, a, keep, Q0, e0, 1)
    Wq = (trend - Q0 @ (Q0.T @ trend))[:, None]
    Wq /= np.linalg.norm(Wq)
    assert null.ratio(e0) * 0.01 > 10 * 0.55  # the trend read as scatter
    assert 0.5 * 0.55 < null.ratio_with(Wq, e0) * 0.01 < 2 * 0.55
    e0 = noise - Q0 @ (Q0.T @ noise)
    null = level_nuisance.null_term(level_nuisance.Levels(C, 2.0), 3.0, a, keep, Q0, e0, 1)
    assert null.ratio(e0) * 0.01 == pytest.approx((3.0 * 2.0) ** 2 / 3, rel=0.05)  # σ² read to ~2 %


def _family(tmp_path: Path, first: int, count: int) -> list[Path]:
    """Fresh outsider nulls (seeds ≥ `first`) whose command is a voltage or duty held on levels
    (staircase, PRBS staircase), drawn behind a noisy tach, an 8-bit bridge and an 8192-count
    encoder (the three named nulls' setting), 20 s; everything else as drawn."""
    out, seed = [], first
    while len(out) < count:
        s = ob.draw(seed, "none", 0.0, closed=False)
        seed += 1
        if s.unit not in ("V", "duty") or s.excitation == "multisine":
            continue
        s.sensor.update(omega="tach", cpr=8192, declare_cpr=True)
        s.drive["pwm_bits"] = 8
        s.seconds = 20.0
        path = tmp_path / f"{s.name}.csv"
        ob.write(path, s, ob.make(s))
        out.append(path)
    return out


@pytest.mark.slow
def test_a_bridges_per_level_error_is_not_named_through_the_encoder(tmp_path: Path) -> None:
    """Six such nulls (seeds 15000…15007): each is read through the encoder and none is named.
    On integ3 they kept the tach (no `omega_source`); through the encoder without the levels in the
    null o15007 was named `saturation` (z 14.0 over a gate of ~3.8: its 8-bit bridge's levels)."""
    cfg = load_config()
    for path in _family(tmp_path, 15000, 6):
        d = doctor.diagnose(load(path, cfg), cfg.plant.v0, seed=0)
        assert speed_source.KEY in d.data.meta, path.name
        assert d.cause == "none", (path.name, d.cause, [(r.cause, r.z) for r in d.ranked[:3]])


@pytest.mark.slow
def test_a_20x_delay_on_a_voltage_staircase_is_named_through_the_encoder(tmp_path: Path) -> None:
    """o12103 as drawn (10 ms delay, V staircase 30 s, 2000 counts, tach): `none` on integ3 (delay
    z 1.45 through the tach), `delay` through the encoder with the levels in the null (z ~170)."""
    path = tmp_path / "o12103.csv"
    ob.write(path, s := ob.draw(12103, "delay", 20.0), ob.make(s))
    p = subprocess.run([TVSCTL, "analyze", str(path), "--json"], capture_output=True, text=True, check=True)
    out = json.loads(p.stdout)
    assert out["cause"] == "delay"
    warn = next(w for w in out.get("warnings", []) if w["code"] == "omega_from_encoder")
    assert "held levels" in warn["reason"]  # the levels in the null are said
