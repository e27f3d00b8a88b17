"""`tvsctl analyze --start S --end E`: the doctor on a window of a recording (tvsd.analysis.window).

Bad windows are bad input: one line naming what was seen and the fix, exit status 2. A window
that cuts a warm-up transient changes the answer as it should: a drive whose supply is still
coming up delivers less than its command for the first seconds, a regime the paper's model does
not describe, and the whole file is not `none`; the window after it is the paper's model again.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tvsd.analysis.dataset import Dataset, load
from tvsd.analysis.sense import MIN_ROWS
from tvsd.analysis.window import cut
from tvsd.cli.main import main
from tvsd.config import load_config
from tvsd.control.setup import Setup
from tvsd.errors import DataFileError
from tvsd.recording.csvfile import write
from tvsd.sim import runs
from tvsd.sim.record import measure, staircase, substeps_for

RATE = 1000.0


def _small(path: Path, seconds: float = 3.0, t0: float = 0.0) -> Path:
    """A moving drive under a ±5 V square wave, `seconds` long from t = t0 (as test_doctor_input)."""
    t = t0 + np.arange(round(seconds * RATE)) / RATE
    u = np.where(((t - t0) % 1) < 0.5, 5.0, -5.0)
    write(path, t, u, np.cumsum(u) / RATE, None, RATE)
    return path


def _analyze_fails(capsys: pytest.CaptureFixture[str], path: Path, *window: str) -> str:
    capsys.readouterr()
    try:
        status = main(["analyze", str(path), "--quiet", *window])
    except SystemExit as exc:  # argparse's own refusal (tvsctl's parser: exit status 2)
        status = exc.code
    assert status == 2
    cap = capsys.readouterr()
    assert cap.out == "" and "Traceback" not in cap.err
    return cap.err


@pytest.mark.parametrize(
    "window,needle",
    [
        (("--start", "5", "--end", "3"), "--start 5 --end 3: the window ends before it starts"),
        (("--start", "2", "--end", "2"), "give an --end greater than --start"),
        (("--start", "50"), "holds no rows: this file's t runs from 10 to 12.999 s"),
        (("--end", "9.5"), "--end 9.5 holds no rows"),
        (("--start", "-20", "--end", "-10"), "holds no rows"),
        (
            ("--start", "10.5", "--end", "10.8"),
            f"keeps 301 rows (0.3 s); the doctor needs at least {MIN_ROWS} rows",
        ),
        (("--start", "12.4"), "widen the window"),
    ],
)
def test_a_bad_window_is_one_line_and_exit_2(tmp_path, capsys, window, needle) -> None:
    """Each bad window: exit 2, one line on stderr saying what was seen and the fix."""
    path = _small(tmp_path / "rec.csv", t0=10.0)  # t from 10 s: the window is on the file's own t
    err = _analyze_fails(capsys, path, *window)
    assert needle in err and err.count("\n") == 1, err


@pytest.mark.parametrize("text", ["abc", "5s", "nan", "inf", "-1e999", ""])
@pytest.mark.parametrize("option", ["--start", "--end"])
def test_a_window_bound_that_is_not_a_number_is_refused(tmp_path, capsys, option, text) -> None:
    """argparse's usage line, then one line naming the option, what it wants and what it got."""
    # --start=TEXT: "-1e999" alone would be read as an option (argparse takes only -5, -2.5 so)
    err = _analyze_fails(capsys, _small(tmp_path / "rec.csv"), f"{option}={text}")
    last = err.strip().splitlines()[-1]
    assert f"argument {option}: expected seconds of the recording's t column" in last, err
    assert repr(text) in last, err


def _dataset(tmp_path: Path, t0: float = 0.0) -> Dataset:
    return load(_small(tmp_path / "rec.csv", 3.0, t0), load_config())


def test_the_window_keeps_the_rows_between_its_bounds_inclusive(tmp_path) -> None:
    d = _dataset(tmp_path, t0=10.0)
    w_data, w = cut(d, 10.5, 12.0)
    # t on a 1 ms grid from 10 s: 10.5 ... 12.0 inclusive is 1501 rows
    assert w.rows == len(w_data.t) == 1501 and w.rows_in_file == 3000
    assert w_data.t[0] == w.t_first_s == pytest.approx(10.5) and w.t_last_s == pytest.approx(12.0)
    np.testing.assert_array_equal(w_data.u, d.u[500:2001])
    np.testing.assert_array_equal(w_data.position, d.position[500:2001])
    assert w.note is None and w.as_json()["start_s"] == 10.5


def test_a_bound_past_the_data_is_clipped_with_a_note(tmp_path) -> None:
    """--end 1e9 means "to the end": clipped to the data, and a note says so (not an error)."""
    d = _dataset(tmp_path)
    _, w = cut(d, 1.0, 1e9)
    assert w.rows == 2000 and w.t_last_s == pytest.approx(2.999)
    assert w.note is not None and "--end 1e+09 is past the last row (t = 2.999 s)" in w.note
    whole, w_all = cut(d, -5.0, None)
    assert whole is d and w_all.rows == 3000 and "--start -5 is before the first row" in str(w_all.note)


def test_a_window_too_short_is_refused_before_the_doctor(tmp_path) -> None:
    with pytest.raises(DataFileError, match="widen the window"):
        cut(_dataset(tmp_path), 0.0, 0.9)  # 901 rows but 0.9 s: under sense.MIN_SECONDS


WARM_UP_S = 5.0  # the drive's supply comes up over this long after power-on
SUPPLY_AT_START = 0.4  # the share of the command the drive delivers at t = 0


def _with_a_supply_warm_up(out: Path, seconds: float, seed: int) -> None:
    """A SIL staircase recording (tvsd.sim.record's staircase, plant and measurement) whose drive
    delivers only a share of its command while its supply comes up: SUPPLY_AT_START at t = 0,
    rising linearly to all of it at WARM_UP_S, all of it after. The file's u is the command, as
    a recorder that logs the controller's output writes it; the shaft's motion is continuous."""
    cfg = load_config()
    m = cfg.sil_or_default.measurement
    setup = Setup.from_config(cfg, effects=(), seed=seed, substeps=substeps_for(cfg, ()))
    decim = round(1.0 / (setup.dt * m.sample_rate_hz))
    rng = np.random.default_rng(seed)
    command = staircase(rng, seconds, setup.u_max, setup.dt)
    t = np.arange(len(command)) * setup.dt
    share = np.clip(SUPPLY_AT_START + (1 - SUPPLY_AT_START) * t / WARM_UP_S, None, 1.0)
    trace = runs.open_loop(setup, command * share, decim)
    cols = measure(trace, m, rng)
    u = command[: len(cols["t"]) * decim].reshape(-1, decim).mean(axis=1)  # as u_mean, undelivered
    meta = {"u_unit": "V", "u_sampling": "mean", "encoder_counts_per_rev": m.encoder_counts_per_rev}
    write(out, cols["t"], u, cols["omega"], cols["phi"], m.sample_rate_hz, meta)


def _doctor(capsys: pytest.CaptureFixture[str], path: Path, *extra: str) -> dict:
    capsys.readouterr()
    assert main(["analyze", str(path), "--json", "--quiet", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def _above_gate(answer: dict) -> list[str]:
    """The candidates that stood above their gate, named or refused by a later check."""
    passed = ("below_gate", "spectral_test")
    return [
        c["cause"]
        for c in answer["candidates"]
        if c["significant"] or (c["why_not"] and c["why_not"]["code"] not in passed)
    ]


def test_cutting_a_warm_up_transient_gives_the_clean_answer(tmp_path, capsys) -> None:
    """The paper's model with white vibration, after a supply warm-up: on the whole file the
    doctor sees what the warm-up leaves (an input gain that rises over 5 s: a candidate above its
    gate — a drift of R that the windowed trend test refuses as a change, not a steady drift; it
    was `colored_noise` before a constant per held level was taken out of the colour test,
    docs/measurements/outsider2.md); --start past the warm-up leaves the paper's model: no
    candidate above its gate and the answer `none` (a 1 % false-alarm rate by construction, fixed
    seed), with the window in the JSON."""
    path = tmp_path / "warm_up.csv"
    _with_a_supply_warm_up(path, 20.0, seed=3)
    whole = _doctor(capsys, path)
    cut_ = _doctor(capsys, path, "--start", f"{WARM_UP_S:g}")
    assert _above_gate(whole), whole["summary"]
    assert "window" not in whole
    assert cut_["cause"] == "none", cut_["summary"]
    assert not _above_gate(cut_), cut_["summary"]
    assert cut_["window"] == {
        "start_s": WARM_UP_S,
        "end_s": None,
        "t_first_s": WARM_UP_S,
        "t_last_s": pytest.approx(20 - 1 / RATE),
        "rows": 15000,
        "rows_in_file": 20000,
    }


def test_the_human_output_and_the_report_state_the_window(tmp_path, capsys) -> None:
    """A short real analysis (3 s square wave) with a window: the first line of the human output
    and the report say which rows were analysed."""
    path = _small(tmp_path / "rec.csv", seconds=4.0)
    capsys.readouterr()
    assert main(["analyze", str(path), "--quiet", "--start", "1", "--report", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "window analysed: t = 1 to 3.999 s (3000 of 4000 rows; --start 1)"
    page = (tmp_path / "rep" / "report.md").read_text()
    assert "Window analysed (--start 1): t = 1 to 3.999 s of the file, 3000 of its 4000 rows" in page
