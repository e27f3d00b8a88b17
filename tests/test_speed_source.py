"""The speed the doctor differentiates: a noisy tach beside an encoder (tvsd.analysis.speed_source).

The outsider bench's tach carries 0.2–2 rad/s of white noise (docs/measurements/outsidereff.md):
differenced into the rows it buried a 6× imbalance (z 0.75) that its own encoder shows at z 99."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import outsider_bench as ob
import pytest

from tvsd.analysis import count_grid, speed_source
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band
from tvsd.config import load_config

TVSCTL = str(Path(sys.executable).parent / "tvsctl")
# ../shared/data/bench-dev beside the checkout (a worktree sits one level deeper: look upwards).
BENCH_DEV = next(
    (d for p in Path(__file__).resolve().parents if (d := p / "shared" / "data" / "bench-dev").is_dir()),
    None,
)


def _write(tmp_path: Path, s: ob.Spec) -> Path:
    path = tmp_path / f"{s.name}-{s.sensor['omega']}.csv"
    ob.write(path, s, ob.make(s))
    return path


def _null(omega: str, seed: int = 13080) -> ob.Spec:
    s = ob.draw(seed, "none", 0.0)  # as o13080 was drawn: a N·m staircase, 2000 counts undeclared, 1 kHz
    s.sensor["omega"] = omega
    s.seconds = 20.0
    return s


def test_a_noisy_tach_is_replaced_by_the_encoders_count_difference(tmp_path: Path) -> None:
    """The drawn tach (white 1.3 % of full scale) leaves ~11× the encoder's equation error (the
    imbalance case drawn from the same seed: 0.088), far past MARGIN (2×); the replacement is
    the snapped angle's difference on its count step, read from φ (the counts are undeclared)."""
    data = load(_write(tmp_path, _null("tach")), load_config())
    chosen = speed_source.choose(data, Band())
    assert chosen is not data and speed_source.KEY in chosen.meta
    step = float(chosen.meta[count_grid.STEP_KEY])
    assert step == pytest.approx(2 * math.pi / 2000 * 1000.0, rel=1e-12)
    assert chosen.speed is not None and count_grid.on_grid(chosen.speed[1:], step)


def test_a_count_difference_an_angle_off_any_grid_or_a_good_speed_keeps_its_speed(tmp_path: Path) -> None:
    """ω already the encoder's difference: nothing to replace. An angle on no grid (a slow creep
    added): nothing to snap to. A closed loop: its rules read the speed fed back. tvsd's own
    bench-dev files (φ on a 4096-count grid, ω its period-mean speed): the count difference leaves ~5× their
    equation error, so ω stays (MARGIN needs it under ½)."""
    data = load(_write(tmp_path, _null("diff")), load_config())
    assert speed_source.choose(data, Band()) is data
    tach = load(_write(tmp_path, _null("tach")), load_config())
    meta = {k: v for k, v in tach.meta.items() if k != "encoder_counts_per_rev"}
    creep = 0.45 * (2 * math.pi / 2000) * tach.t / tach.t[-1]  # to 0.45 count: past SNAP_TOL (¼)
    off_grid = replace(tach, position=tach.position + creep, meta=meta)
    assert speed_source.counts_step(off_grid) is None
    assert speed_source.choose(off_grid, Band()) is off_grid
    closed = replace(tach, refs={"omega_ref": tach.u})  # the closed loop's rules keep their speed
    assert speed_source.choose(closed, Band()) is closed
    for path in [BENCH_DEV / n for n in ("d00.csv", "d05.csv")] if BENCH_DEV is not None else []:
        dev = load(path, load_config())
        found = speed_source.compared(dev, Band())
        assert found is None or found[1] > 1.0
        assert speed_source.choose(dev, Band()) is dev


def test_a_voltage_on_levels_at_500_hz_counts_the_rows_the_doctor_has(tmp_path: Path) -> None:
    """A voltage held on levels is compared, its levels carried by the null
    (tvsd.analysis.level_nuisance) with the rows the doctor's own level check (without_levels)
    sees (review5 found them apart while a 500 Hz file was decimated ×2 and a guard counted ×4).
    40 levels in 10⁴ samples at 500 Hz: levels to both; past level_nuisance.MAX_CELLS the speed is
    kept (the block would be too large to carry)."""
    from tvsd.analysis import command_levels, level_nuisance
    from tvsd.analysis.prep import prepare

    s = _null("tach")
    s.fs = 500.0
    data = load(_write(tmp_path, s), load_config())
    stair = np.repeat(np.random.default_rng(1).uniform(-1, 1, 40), math.ceil(len(data.u) / 40))
    volts = replace(data, u=stair[: len(data.u)], u_unit="V")
    prep = prepare(volts, Band())
    rows = len(prep.rows(volts.u))
    assert command_levels.usable_levels(volts.u, False, rows) is not None  # the doctor sees levels
    levels = level_nuisance.columns(prep)
    assert levels is not None and levels.columns.shape == (rows, 40)
    assert speed_source.compared(volts, Band()) is not None
    assert level_nuisance.fits(volts, rows) and not level_nuisance.fits(volts, level_nuisance.MAX_CELLS // 39)


@pytest.mark.slow
def test_a_6x_imbalance_behind_a_noisy_tach_is_named(tmp_path: Path) -> None:
    """o13080 as drawn (N·m staircase 30 s, 2000 counts undeclared, tach): `none` on integ3
    (imbalance z 0.75 under a gate of ~3.6), `imbalance` through the encoder (z ~99: far from it)."""
    path = _write(tmp_path, ob.draw(13080, "imbalance", 6.0))
    p = subprocess.run([TVSCTL, "analyze", str(path), "--json"], capture_output=True, text=True, check=True)
    out = json.loads(p.stdout)
    assert out["cause"] == "imbalance"
    assert any(w["code"] == "omega_from_encoder" for w in out.get("warnings", []))


def test_a_recordings_own_omega_source_line_is_not_the_doctors_note(tmp_path: Path) -> None:
    """`# omega_source:` is a recording's own optional header key (a daemon export describes its ω
    with it). The doctor once kept its own note under that name, so every such file was reported
    `omega_from_encoder` (and, on a voltage staircase, would have had the levels in its null)
    though its speed was its own: a count-difference file with that line keeps its speed, no
    warning, and the file's text is not the sentence's note."""
    path = _write(tmp_path, _null("diff"))
    lines = path.read_text().splitlines()
    own = "the MCU's encoder frames at their sampling instants (as tvsctl export writes it)"
    path.write_text("\n".join([lines[0], f"# omega_source: {own}", *lines[1:]]) + "\n")
    data = load(path, load_config())
    assert data.meta["omega_source"] == own
    assert speed_source.KEY not in speed_source.choose(data, Band()).meta
    p = subprocess.run([TVSCTL, "analyze", str(path), "--json"], capture_output=True, text=True, check=True)
    out = json.loads(p.stdout)
    assert not any(w["code"] == "omega_from_encoder" for w in out.get("warnings", []))
    assert own not in out["summary"]
