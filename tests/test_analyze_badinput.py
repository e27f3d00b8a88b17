"""Bad recordings found by scripts/analyze_fuzz.py (docs/measurements/badinput.md): each gets one
line naming what was seen, where (row, column) and the fix, and exit status 2; what is
unambiguous (UTF-16 with its byte order mark, a negative bound in any float form) is read."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest
from csv_helpers import square_wave_csv

from tvsd.analysis import dataset
from tvsd.cli.main import build_parser, main
from tvsd.config import load_config
from tvsd.errors import DataFileError
from tvsd.recording import csvfile


def _valid(tmp_path: Path, meta: str = "# source: bench") -> Path:
    path = tmp_path / "valid.csv"
    square_wave_csv(path, meta)
    return path


def _lines(tmp_path: Path) -> list[str]:
    return _valid(tmp_path).read_text().splitlines()


def _write(tmp_path: Path, lines: list[str], end: str = "\n") -> Path:
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(lines) + end)
    return path


def test_a_gzip_file_is_named_as_such(tmp_path: Path) -> None:
    """Before: "not a text file (expected a tvs recording CSV)": no cause, no fix."""
    path = tmp_path / "rec.csv"
    path.write_bytes(gzip.compress(_valid(tmp_path).read_bytes()))
    with pytest.raises(DataFileError, match="gzip-compressed file; decompress it first"):
        csvfile.read(path)


def test_utf16_with_its_byte_order_mark_is_read(tmp_path: Path) -> None:
    """A Windows editor's "Unicode" save: the BOM says how to read it, nothing is guessed.
    Before: refused as "not a text file"."""
    src = _valid(tmp_path)
    path = tmp_path / "utf16.csv"
    path.write_bytes(src.read_text().encode("utf-16"))
    assert np.array_equal(csvfile.read(path).omega, csvfile.read(src).omega)


def test_a_latin1_byte_names_its_row_and_the_fix(tmp_path: Path) -> None:
    lines = _lines(tmp_path)
    path = tmp_path / "latin1.csv"
    path.write_bytes(("\n".join([lines[0], "# operator: M\xfcller", *lines[1:]]) + "\n").encode("latin-1"))
    with pytest.raises(DataFileError, match=r"row 2: byte 0xfc is not UTF-8 .*save the file as UTF-8"):
        csvfile.read(path)


def test_nul_bytes_are_binary_not_a_missing_sample_rate(tmp_path: Path) -> None:
    """Before: "row 2: missing '# sample_rate_hz: <Hz>' metadata line" (its line held a NUL)."""
    lines = _lines(tmp_path)
    path = _write(tmp_path, [lines[0], "\0" + lines[1], *lines[2:]])
    with pytest.raises(DataFileError, match="row 2: a NUL byte"):
        csvfile.read(path)


@pytest.mark.parametrize(
    "meta,needle",
    [
        (["# u_unit: volts"], "row 4: u_unit 'volts'"),
        (["# u_unit: duty", "# u_scale: 0"], r"row 5: u_unit duty needs .*got '0'"),
        (["# sample_rate_hz: 1 kHz"], None),  # a second, contradictory line: refused where it is
    ],
)
def test_a_metadata_error_names_the_row_of_its_line(
    tmp_path: Path, meta: list[str], needle: str | None
) -> None:
    """Before: every unit error said "row 2", wherever the line was."""
    lines = _lines(tmp_path)
    path = _write(tmp_path, [*lines[:3], *meta, *lines[3:]])
    with pytest.raises(DataFileError, match=needle or "row 4: 'sample_rate_hz' is given again"):
        csvfile.read(path)


def _edit(tmp_path: Path, row: int, line: str) -> Path:
    lines = _lines(tmp_path)
    return _write(tmp_path, [*lines[: row - 1], line, *lines[row:]])


@pytest.mark.parametrize(
    "line,needle",
    [
        ("", r"row 1000: an empty line inside the data .*delete it"),
        ("# paused", r"row 1000: a comment line '# paused' inside the data: comments go above"),
        ("0,9960,5,0", r"row 1000: 4 values .*\(decimal commas\? the recording CSV uses '.'"),
        ("0.996,5.0,-0.5,", r"row 1000: 4 values .*\(a trailing comma\)"),
        ("0.996,5.0", r"row 1000: 2 values .*the header t,u,omega has 3 \(a cut or merged line\)"),
        ("0.996,,1.0", r"row 1000: u is empty in '0.996,,1.0': repair or delete the row"),
        ("0.996,5.0,fast", r"row 1000: omega is 'fast', not a number"),
    ],
)
def test_a_bad_row_says_what_it_likely_is_and_the_fix(tmp_path: Path, line: str, needle: str) -> None:
    """Before: "1 values, the header has 4 columns" or "not a number in …": no column, no fix."""
    with pytest.raises(DataFileError, match=needle):
        csvfile.read(_edit(tmp_path, 1000, line))


def test_a_last_row_cut_while_writing_says_so(tmp_path: Path) -> None:
    """A recording copied while it was written ends mid-row, with no end of line."""
    text = _valid(tmp_path).read_text().rstrip("\n")
    path = tmp_path / "cut.csv"
    path.write_text(text[: text.rfind(",") + 1])  # '…,': cut before its last value
    with pytest.raises(DataFileError, match=r"row 3004: the last row .* is cut short .*delete that row"):
        csvfile.read(path)


@pytest.mark.parametrize(
    "last,needle",
    [
        ("2.999,5.0,fast", r"row 3004: omega is 'fast', not a number in '2.999,5.0,fast'"),
        ("2.999,slow,1.0", r"row 3004: u is 'slow', not a number"),
        ("2.999,5.0,1.5e", r"row 3004: the last row .* is cut short"),
        ("2.999,5.0,-", r"row 3004: the last row .* is cut short"),
    ],
)
def test_a_whole_last_row_with_a_word_is_a_non_number_not_cut(tmp_path: Path, last: str, needle: str) -> None:
    """Before: a complete last row with no end of line and a word in it was "cut short"; every
    field is there, so it is the non-number it is (its column named). A last field that is the
    start of a number ('1.5e', '-') is still a number cut while written (review4.md)."""
    lines = _lines(tmp_path)
    with pytest.raises(DataFileError, match=needle):
        csvfile.read(_write(tmp_path, [*lines[:-1], last], end=""))


@pytest.mark.parametrize("text,value", [("-1e3", -1000.0), ("-2.5E-1", -0.25), ("-5", -5.0)])
def test_a_negative_bound_in_any_float_form_is_a_value(text: str, value: float) -> None:
    """argparse took `-1e3` for an option: "argument --start: expected one argument", exit 2 on
    a finite number of seconds (a t column may start below 0)."""
    args = build_parser(["analyze"]).parse_args(["analyze", "x.csv", "--start", text])
    assert args.start == value


def test_a_heldout_file_of_another_unit_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Before: judged, and a verdict printed, with the volt model simulated on amperes."""
    fit = _valid(tmp_path)
    other = tmp_path / "amps.csv"
    square_wave_csv(other, "# u_unit: A")
    with pytest.raises(DataFileError, match=r"amps.csv: --heldout's command u is in A \(rotary\)"):
        dataset.check_heldout(dataset.load(fit, load_config()), dataset.load(other, load_config()))
    assert main(["analyze", str(fit), "--heldout", str(other), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--heldout's command u is in A" in err and err.count("\n") == 1, err
