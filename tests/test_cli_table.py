"""`tvsctl`'s tables (tvsd.cli.output.print_table): numbers right-aligned, text left-aligned, and
no line padded at its end — a long text cell (a fault's message) used to right-align every row of
its column, so `tvsctl faults` printed thousands of spaces per row (found by branch newuser)."""

from __future__ import annotations

import pytest

from tvsd.cli.output import print_table


def test_text_is_left_aligned_numbers_right_and_no_line_ends_in_spaces(
    capsys: pytest.CaptureFixture[str],
) -> None:
    long_message = "x" * 300
    print_table([["mcu_stale", 3, long_message], ["imu", 12, "short"]], ["cause", "count", "message"])
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["cause", "count", "message"]
    assert all(line == line.rstrip() for line in lines)
    # the short message's row is as long as its text, not padded to the long one's width
    assert lines[3].endswith("short") and len(lines[3]) < 40
    # the count column: right-aligned (its digits end in the same column)
    assert lines[2].index("3") + 1 == lines[3].index("12") + 2


def test_an_empty_table_prints_its_header_only(capsys: pytest.CaptureFixture[str]) -> None:
    print_table([], ["cause", "count"])
    assert capsys.readouterr().out.split() == ["cause", "count", "-----", "-----"]


def test_numpy_numbers_are_right_aligned_like_python_numbers(capsys: pytest.CaptureFixture[str]) -> None:
    """A column of numpy scalars (what a bench's or the doctor's arrays hand the table) lines up
    its digits as a column of ints and floats does; before, `np.int64` was text (left-aligned) and
    an `np.float32` NaN printed "nan", not the table's "—". numpy bools stay text, like bool."""
    import numpy as np

    rows = [["a", np.int64(3), np.float32(0.5)], ["b", np.int64(120), np.float32("nan")]]
    print_table(rows, ["k", "n", "x"])
    numpy_lines = capsys.readouterr().out.splitlines()
    print_table([["a", 3, 0.5], ["b", 120, float("nan")]], ["k", "n", "x"])
    assert numpy_lines == capsys.readouterr().out.splitlines()
    assert numpy_lines[2].index("3") == numpy_lines[3].index("120") + 2  # digits end together
    print_table([[np.bool_(True)], [np.bool_(False)]], ["ok"])
    assert capsys.readouterr().out.splitlines()[2:] == ["True", "False"]
