"""`tvsctl analyze` on an export with gap-filled rows (`gap` = 1; found by branch newuser).

A non-realtime daemon's export had 428 gaps, 8339 of 17626 rows interpolated, and the doctor
answered as for any file. Now it warns (a few filled rows) or refuses, exit 2 (most of the rows
the fit sees are within the filters' reach of filled ones).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tvsd.cli.main import main
from tvsd.recording.csvfile import read, write


@pytest.fixture(scope="module")
def clean(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("gaps") / "clean.csv"
    assert main(["sim", "record", "--out", str(out), "--seconds", "12", "--seed", "3"]) == 0
    return out


def _with_gaps(clean: Path, out: Path, every: int, length: int, first: int) -> tuple[Path, int]:
    """The clean recording with runs of `length` rows replaced by the line between their
    neighbours and flagged gap = 1, one run per `every` rows from row `first` on: as tvsctl export
    fills a stall."""
    rec = read(clean)
    u, omega, phi = rec.u.copy(), rec.omega.copy(), rec.phi.copy()
    gap = np.zeros(len(rec.t))
    for start in range(first, len(rec.t) - length - 1, every):
        stop = start + length  # rows start..stop-1 filled between start-1 and stop
        for col in (u, omega, phi):
            col[start:stop] = np.interp(rec.t[start:stop], rec.t[[start - 1, stop]], col[[start - 1, stop]])
        gap[start:stop] = 1.0
    write(out, rec.t, u, omega, phi, rec.sample_rate_hz, rec.meta, {**rec.extra, "gap": gap})
    return out, int(gap.sum())


def test_mostly_filled_rows_are_refused(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the stranger's export: a gap of ~19.5 rows every ~41 (8339 of 17626 rows, 47 %)
    path, n_filled = _with_gaps(clean, tmp_path / "stalled.csv", every=41, length=19, first=20)
    capsys.readouterr()
    assert main(["analyze", str(path), "--quiet"]) == 2  # before: 0, a verdict
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{n_filled} of " in err and "no verdict" in err, err


def test_a_few_filled_rows_are_named_on_stderr(
    clean: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # one 20-row stall in the middle (20 ms at 1 kHz): analysed, and said
    n = len(read(clean).t)
    path, _ = _with_gaps(clean, tmp_path / "one.csv", every=n, length=20, first=n // 2)
    capsys.readouterr()
    assert main(["analyze", str(path), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: one.csv: 20 of ") and "1 gap(s)" in err, err  # before: nothing


def test_a_gap_column_of_zeros_says_nothing(clean: Path, tmp_path: Path) -> None:
    from tvsd.analysis.dataset import load
    from tvsd.analysis.prep import Band, check_filled
    from tvsd.config import load_config

    path, n_filled = _with_gaps(clean, tmp_path / "none.csv", every=10**9, length=0, first=10**9)
    assert n_filled == 0
    assert check_filled(load(path, load_config()), Band()) is None
