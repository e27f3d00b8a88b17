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
