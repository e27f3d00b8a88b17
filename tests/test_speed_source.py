"""The speed the doctor differentiates: a noisy tach beside an encoder (tvsd.analysis.speed_source).

The outsider bench's tach carries 0.2–2 rad/s of white noise (docs/measurements/outsidereff.md):
differenced into the rows it buried a 20× delay (z 1.45) that its own encoder shows at z 167."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import outsider_bench as ob
import pytest

from tvsd.analysis import count_grid, speed_source
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band
from tvsd.config import load_config

TVSCTL = str(Path(sys.executable).parent / "tvsctl")
BENCH_DEV = Path(__file__).resolve().parent.parent / "../shared/data/bench-dev"


def _write(tmp_path: Path, s: ob.Spec) -> Path:
    path = tmp_path / f"{s.name}-{s.sensor['omega']}.csv"
    ob.write(path, s, ob.make(s))
    return path


def _null(omega: str) -> ob.Spec:
    s = ob.draw(12103, "none", 0.0, closed=False)  # a V staircase, 2000 counts declared, 1 kHz
    s.sensor["omega"] = omega
    s.seconds = 20.0
    return s


def test_a_noisy_tach_is_replaced_by_the_encoders_count_difference(tmp_path: Path) -> None:
    """The drawn tach (white 1.6 % of full scale) leaves ~30× the encoder's equation error, far
    past MARGIN (2×); the replacement is the snapped angle's difference on its count step."""
    data = load(_write(tmp_path, _null("tach")), load_config())
    chosen = speed_source.choose(data, Band())
    assert chosen is not data and speed_source.KEY in chosen.meta
    step = float(chosen.meta[count_grid.STEP_KEY])
    assert step == pytest.approx(2 * 3.141592653589793 / 2000 * 1000.0, rel=1e-12)
    assert chosen.speed is not None and count_grid.on_grid(chosen.speed[1:], step)


def test_a_count_difference_or_an_angle_off_any_grid_keeps_its_speed(tmp_path: Path) -> None:
    """ω already the encoder's difference: nothing to replace. A continuous angle (tvsd's own
    bench-dev files: no grid to snap to): the recorded speed stays."""
    data = load(_write(tmp_path, _null("diff")), load_config())
    assert speed_source.choose(data, Band()) is data
    tach = load(_write(tmp_path, _null("tach")), load_config())
    meta = {k: v for k, v in tach.meta.items() if k != "encoder_counts_per_rev"}
    off_grid = replace(tach, position=tach.position + 1e-3 * tach.t, meta=meta)  # a slow creep
    assert speed_source.choose(off_grid, Band()) is off_grid
    for name in ("d00.csv", "d05.csv"):
        dev = load(BENCH_DEV / name, load_config())
        assert speed_source.choose(dev, Band()) is dev


@pytest.mark.slow
def test_a_20x_delay_behind_a_noisy_tach_is_named(tmp_path: Path) -> None:
    """o12103 as drawn (10 ms, V staircase 30 s, 2000 counts, tach): `none` on integ3 (delay
    z 1.45 under a gate of ~3.6), `delay` through the encoder (z ~167: far from the gate)."""
    path = _write(tmp_path, ob.draw(12103, "delay", 20.0))
    p = subprocess.run([TVSCTL, "analyze", str(path), "--json"], capture_output=True, text=True, check=True)
    out = json.loads(p.stdout)
    assert out["cause"] == "delay"
    assert any(w["code"] == "omega_from_encoder" for w in out.get("warnings", []))
