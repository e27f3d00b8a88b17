"""`# u_sampling:` — how the command column was sampled, and the delay it makes when unknown.

tvsd's recordings hold u and ω as means over the same interval (the one that ends at the row's
time). A bench that holds each command from its sample on applies it one sample later: a pure
delay, phase −ωτ, the very shape of the `delay` cause, so the recording cannot tell the two
apart. On the outsider generator's nulls (held commands) that sample, plus a drive's own
sub-sample lags, was named `delay` 1.09-1.59 samples (docs/measurements/lagdelay.md). Declared,
a hold is undone on load; undeclared, a delay must exceed two samples to be a cause.
"""

from __future__ import annotations

import numpy as np
import pytest
from csv_helpers import square_wave_csv

from tvsd.analysis.dataset import load
from tvsd.cli.main import main
from tvsd.config import load_config
from tvsd.recording.csvfile import read


@pytest.mark.parametrize("value", ["sideways", "", "Hold"])
def test_an_unknown_sampling_is_one_line_exit_2(tmp_path, capsys, value) -> None:
    path = tmp_path / "bad.csv"
    square_wave_csv(path, f"# u_sampling: {value}")
    assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "u_sampling" in err and "mean, hold" in err and err.count("\n") == 1, err


def test_a_held_command_is_moved_one_sample_later_on_load(tmp_path) -> None:
    """Held from sample k on, u[k] acts over the interval that ends at sample k+1: row k+1 in
    tvsd's convention. A mean (or no line) leaves u as recorded."""
    held, mean, bare = tmp_path / "held.csv", tmp_path / "mean.csv", tmp_path / "bare.csv"
    square_wave_csv(held, "# u_sampling: hold")
    square_wave_csv(mean, "# u_sampling: mean")
    square_wave_csv(bare, "# source: a bench")
    cfg = load_config()
    u = read(bare).u
    assert np.array_equal(load(bare, cfg).u, u) and np.array_equal(load(mean, cfg).u, u)
    got = load(held, cfg).u
    assert got[0] == u[0] and np.array_equal(got[1:], u[:-1])


def test_tvsd_recordings_declare_their_mean(tmp_path) -> None:
    from tvsd.sim.record import record

    out = tmp_path / "r.csv"
    record(load_config(), out, "multisine", 2.0, (), seed=1)
    assert read(out).meta["u_sampling"] == "mean"
