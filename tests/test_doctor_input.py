"""Bad input to the model doctor: one clear line, exit status 2, no numpy warning on stderr."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from tvsd.cli.main import main


def _write(path, t, u, omega, meta=""):
    lines = ["# tvs-recording: 1", "# sample_rate_hz: 1000", *([meta] if meta else []), "t,u,omega"]
    lines += [f"{a:.4f},{b!r},{c!r}" for a, b, c in zip(t, map(float, u), map(float, omega), strict=True)]
    path.write_text("\n".join(lines) + "\n")


T = np.arange(3000) / 1000
SQUARE = np.where((T % 1) < 0.5, 5.0, -5.0)
MOVING = np.cumsum(SQUARE) / 1000


@pytest.mark.parametrize(
    "name,t,u,omega,meta,needle",
    [
        ("rows2", T[:2], SQUARE[:2], MOVING[:2], "", "only 2 rows"),
        ("rows10", T[:10], SQUARE[:10], MOVING[:10], "", "only 10 rows"),
        ("zeros", T, 0 * T, 0 * T, "", "the command u is constant"),
        ("constant", T, 3 + 0 * T, np.linspace(0, 5, len(T)), "", "no excitation"),
        ("still", T, SQUARE, 0 * T, "", "the drive did not move"),
        ("huge", T, SQUARE, np.where(T > 1, 1e308, MOVING), "", "not a measurement"),
        ("unit", T, SQUARE, MOVING, "# u_unit: volts", "u_unit 'volts'"),
        ("duty", T, SQUARE, MOVING, "# u_unit: duty", "u_scale"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, name, t, u, omega, meta, needle):
    path = tmp_path / f"{name}.csv"
    _write(path, t, u, omega, meta)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy warning would be an error here
        assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err
