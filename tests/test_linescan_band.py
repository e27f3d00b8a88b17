"""The rows hold the band at every sample rate, so the line scan reaches a mode above 50 Hz.

At 500 Hz a fixed ×4 decimation left 125 Hz rows whose anti-alias filter ended at 50 Hz: a
structural mode at 50–80 Hz (the scan's reach at 1–2 kHz) was filtered out before any test saw it
(docs/measurements/linescan2.md). The decimation is now the largest whose anti-alias corner is
not below the band's corner (×2 at 500 Hz: the same 250 Hz rows as at 1 kHz).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from tvsd.analysis.prep import EMPS_BAND, Band
from tvsd.causes import parse_effect
from tvsd.cli.main import main
from tvsd.config import load_config
from tvsd.sim.record import record


@pytest.mark.parametrize("fs,decim", [(250.0, 1), (500.0, 2), (800.0, 3), (1000.0, 4), (2000.0, 4)])
def test_the_rows_anti_alias_corner_is_never_below_the_bands(fs: float, decim: int) -> None:
    band = Band().at_rate(fs)
    assert band.decim == decim
    assert 0.4 * fs / band.decim >= band.cutoff_hz  # cheby1's corner, 0.8 of the rows' Nyquist


def test_emps_keeps_its_published_decimation() -> None:
    assert EMPS_BAND.at_rate(1000.0).decim == 10


def _record_500(tmp: Path, effects: list[str], seed: int) -> Path:
    cfg = load_config()
    sil = cfg.sil_or_default
    sil = dataclasses.replace(sil, measurement=dataclasses.replace(sil.measurement, sample_rate_hz=500.0))
    cfg = dataclasses.replace(cfg, sil=sil)
    out = tmp / "r500.csv"
    record(cfg, out, "steps", 30.0, tuple(parse_effect(e) for e in effects), seed)
    return out


@pytest.mark.slow
def test_a_mode_above_50_hz_at_500_hz_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 65 Hz mode at the size tests/test_doctor.py names at 43 Hz (2e-4 N·m). Before: the
    500 Hz rows ended at 50 Hz, the scan too, and the answer was `none`. The frequency within
    0.1 Hz, test_doctor's tolerance (a 30 s record's bin is 0.033 Hz)."""
    path = _record_500(tmp_path, ["resonance:frequency_hz=65.0,amplitude=2e-4"], 17)
    capsys.readouterr()
    assert main(["analyze", str(path), "--json", "--quiet"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["cause"] == "resonance", res["candidates"][:2]
    assert abs(res["effect"]["frequency_hz"] - 65.0) <= 0.1
