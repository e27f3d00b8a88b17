"""A drive that never moves clear of its speed noise is no excitation: one line, exit status 2
(issue 12 item 7; tvsd.analysis.excitation). A drive that breaks away only briefly is analysed."""

from __future__ import annotations

import numpy as np
import pytest

from tvsd.analysis import excitation as X
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.cli.main import main
from tvsd.config import load_config

FS = 1000
SIGMA = 0.02  # rad/s: the SIL's speed_noise_rad_s


def _write(path, t, u, omega):
    lines = ["# tvs-recording: 1", f"# sample_rate_hz: {FS}", "t,u,omega"]
    lines += [f"{a:.4f},{b!r},{c!r}" for a, b, c in zip(t, map(float, u), map(float, omega), strict=True)]
    path.write_text("\n".join(lines) + "\n")


def _sticking_drive(seconds: float, kick_s: float, seed: int) -> tuple[np.ndarray, ...]:
    """A rigid drive with Coulomb friction, ω̇ = a·u − c·ω − f·sgn ω, stuck while |a·u| ≤ f:
    a ±4 V square wave never breaks it; a ±10 V pulse of kick_s at each reversal does."""
    n = int(seconds * FS)
    t = np.arange(n) / FS
    u = np.where((t % 1) < 0.5, 4.0, -4.0)
    u[(t % 2.0) < kick_s] = 10.0
    u[((t - 1.0) % 2.0) < kick_s] = -10.0
    a, c, f = 20.0, 0.4, 100.0  # rad/s² per V, 1/s, rad/s²
    w = np.zeros(n)
    for k in range(1, n):
        if w[k - 1] == 0 and abs(a * u[k - 1]) <= f:
            continue  # stuck
        nw = w[k - 1] + (a * u[k - 1] - c * w[k - 1] - f * np.sign(w[k - 1])) / FS
        w[k] = 0.0 if w[k - 1] != 0 and np.sign(nw) != np.sign(w[k - 1]) else nw
    return t, u, w + np.random.default_rng(seed).normal(0.0, SIGMA, n)


def test_stuck_drive_is_refused_as_no_excitation(tmp_path, capsys):
    """Before: the noise's sign went into the friction column and the file came out
    `model_mismatch` ("the command does not accelerate the shaft … wrong sign or unit of u")."""
    t, u, omega = _sticking_drive(20.0, 0.0, seed=1)  # never kicked: the speed is noise alone
    path = tmp_path / "stuck.csv"
    _write(path, t, u, omega)
    assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "no excitation" in err and err.count("\n") == 1, err


@pytest.mark.slow  # a whole analysis: 55 s on a loaded 2-core machine
def test_drive_moving_briefly_near_the_threshold_is_analysed(tmp_path, capsys):
    """5 ms kicks: the shaft moves ~2.5 % of the time, peaks ~36 σ. Its moving rows are within 2×
    of the ROWS_PER_COLUMN·columns the check needs, and it is analysed, not refused."""
    t, u, omega = _sticking_drive(20.0, 0.005, seed=3)
    path = tmp_path / "kicked.csv"
    _write(path, t, u, omega)
    prep = prepare(load(path, load_config()), Band())
    moving = np.count_nonzero(np.abs(prep.rows(prep.speed)) > X.CLEAR * X.row_noise(prep))
    need = X.ROWS_PER_COLUMN * 8  # the baseline's columns: a0, a1, c, f, s and three absorber shapes
    assert need <= moving < 2 * need, moving
    assert main(["analyze", str(path), "--quiet"]) == 0, capsys.readouterr().err


@pytest.mark.parametrize("seed", range(4))
def test_speed_noise_is_estimated_from_the_data(tmp_path, seed):
    """σ̂ from the second differences, on a moving drive: within 6 % of the σ the file was made
    with. σ̂'s standard error on 20 000 white samples is 0.93 % (measured over 200 seeds), so 6 %
    is over 6 standard errors, with room for the drive's own few large differences (the kicks)."""
    t, u, omega = _sticking_drive(20.0, 0.04, seed=seed)
    path = tmp_path / "moving.csv"
    _write(path, t, u, omega)
    prep = prepare(load(path, load_config()), Band())
    assert X.speed_noise(prep) == pytest.approx(SIGMA, rel=0.06)
