"""Bad input a stranger typed, found by walking the README from a fresh clone and a wheel install:
each was an internal error (exit 70), a numpy warning, or a NaN result with exit 0. Now each is
the usage and one line naming the option's range, exit 2 (EXIT_USAGE), before anything runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from tvsd.cli.main import main
from tvsd.errors import EXIT_USAGE

# argv -> the option the refusal must name; what each did before is in the comment
REFUSED = [
    (["analyze", "rec.csv", "--seed", "-1"], "--seed"),  # 70: ValueError from numpy's SeedSequence
    (["sim", "record", "--out", "r.csv", "--seconds", "1", "--seed", "-1"], "--seed"),  # 70
    (["sim", "scan", "--seconds", "1", "--seed", "-1"], "--seed"),  # 70
    (["sim", "spin", "--rps", "25", "--seed", "9" * 23], "--seed"),  # 70: numba TypingError
    (["sim", "record", "--out", "r.csv", "--profile", "spin", "--rps", "nan"], "--rps"),  # 0, rps nan
    (["sim", "table6", "--ku", "-1"], "--ku"),  # exit 0 with a table of NaN errors
    (["sim", "table6", "--ku", "0"], "--ku"),  # 70: ZeroDivisionError
    (["imu", "capture", "--sil", "--seconds", "1", "--seed", "-1"], "--seed"),  # 70
    (["imu", "capture", "--sil", "--seconds", "1", "--rps", "nan"], "--rps"),  # 70: float NaN to int
    (["imu", "capture", "--sil", "--seconds", "1", "--rps", "1e308"], "--rps"),  # 70: OverflowError
    (["imu", "capture", "--sil", "--seconds", "1", "--imbalance", "nan"], "--imbalance"),  # exit 0
    (["imu", "capture", "--sil", "--resonance-hz", "1e308", "--resonance", "1"], "--resonance-hz"),  # warning
    (["imu", "capture", "--sil", "--seconds", "1", "--gamma-deg", "nan"], "--gamma-deg"),  # warning
    (["imu", "bench", "--seconds", "-1"], "--seconds"),  # exit 0
    (["mcu", "ping", "--sil", "--count", "1", "--interval", "nan"], "--interval"),  # exit 0
    (["mcu", "stats", "--sil", "--seconds", "nan"], "--seconds"),  # exit 0
]


@pytest.mark.parametrize(("argv", "option"), REFUSED, ids=[" ".join(a) for a, _ in REFUSED])
def test_a_number_out_of_range_is_refused_before_anything_runs(
    argv: list[str], option: str, capsys: pytest.CaptureFixture[str], tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.chdir(tmp_path)  # nothing may be written; if something were, not into the checkout
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == EXIT_USAGE
    err = capsys.readouterr().err
    last = err.strip().splitlines()[-1]
    assert f"argument {option}: expected" in last, err
    assert "Traceback" not in err and "internal error" not in err and "Warning" not in err
    assert list(tmp_path.iterdir()) == []


def test_sim_record_spin_refuses_a_speed_the_drive_cannot_hold(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`sim spin` refused --rps 0 and `sim record --profile spin` wrote a recording of it."""
    out = tmp_path / "r.csv"
    argv = ["sim", "record", "--out", str(out), "--profile", "spin", "--rps", "0", "--seconds", "1"]
    assert main(argv) == 2
    assert "outside the drive's range" in capsys.readouterr().err
    assert not out.exists()
