"""The spectral peak test leaves out the command's own lines, as the line scan does
(docs/measurements/freshnulls.md): a rigid model that misfits the drive's response to a
multisine line leaves a narrow peak exactly there, which no residual test can tell from a mode.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import outsider_bench as ob

from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.linescan import command_lines_hz
from tvsd.config import load_config


def test_command_lines_are_the_multisines_and_not_the_noises() -> None:
    """A multisine (the outsider bench's 12 lines, 0.3–25 Hz) on white noise, 30 s of the
    doctor's 250 Hz rows: each line found within one bin (1/30 Hz) and none elsewhere; the
    white noise alone passes the detection level with probability 1 % (its design), and this
    seed's draw has no line."""
    fs, n = 250.0, 7500
    t = np.arange(n) / fs
    # Lines on the record's Fourier grid (a whole number of periods): one bin each.
    lines = np.round(np.geomspace(0.3, 25.0, 12) * n / fs) * fs / n
    g = np.random.default_rng(3)
    u = sum(np.sin(2 * np.pi * f * t + g.uniform(0, 2 * np.pi)) for f in lines)
    noise = g.standard_normal(n)
    found = command_lines_hz([u + noise], fs)
    assert len(found) == len(lines)
    assert np.all(np.abs(np.sort(found) - lines) <= fs / n + 1e-9)
    assert command_lines_hz([noise], fs) == ()


def test_a_multisine_top_line_is_not_a_mode(tmp_path: Path) -> None:
    """Outsider null o14120 (V PWM drive, multisine 0.3–25 Hz, 30 s) drawn with a fine encoder
    (4194304 counts: no quantisation floor): the residual's spectral peak is the multisine's top
    line, 24.9 Hz; the file declares no `# excitation_hz:`. Was `resonance` at 24.90 Hz (peak
    test score 63.7, on integ3 at f65112f too); the line is detected in the command, so left out."""
    s = copy.deepcopy(ob.draw(14120, "none", 0.0))
    s.sensor["cpr"] = 4194304
    path = tmp_path / "o14120-fine.csv"
    ob.write(path, s, ob.make(s))
    cfg = load_config()
    dg = diagnose(load(path, cfg), cfg.plant.v0)
    assert dg.cause == "none", (dg.cause, dg.effect)
