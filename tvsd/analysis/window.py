"""`tvsctl analyze --start S --end E`: the model doctor on a window of a recording.

Why: a recording often begins and ends in a regime the drive model is not asked to describe (a
drive not yet enabled, a spin-up against a cold bearing, a shutdown): left in, it is what the
doctor names. The window is in seconds of the recording's own `t` column, as written in the file
(an EMPS .mat file's `t` counted from its first value, which is 0 in the benchmark's files), and
keeps the rows with S ≤ t ≤ E; either bound may be left out (the file's first or last row).
Everything the doctor does then sees the window only: its fit on the first two thirds, its
judgement on the last third (a `--heldout` file is judged whole). The window is cut after
loading: a held-sample `u` (`u_sampling: hold`) keeps the row before the window as its first
value, as in the whole file, and the instrument's properties read at loading (the speed
column's timing, the encoder's count step) come from the whole file, the more rows the better.

Bad windows are bad input (UsageError or DataFileError: one line, exit status 2): an end not
after the start, a window that holds no row of the file, a window left with fewer rows or
seconds than the doctor needs (sense.MIN_ROWS, sense.MIN_SECONDS). A bound past the file's
edge is not an error (`--end 1e9`: to the end): the window is clipped to the data and a note says
so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tvsd.analysis.dataset import Dataset
from tvsd.analysis.sense import MIN_ROWS, MIN_SECONDS
from tvsd.errors import DataFileError, UsageError


def describe(start: float | None, end: float | None) -> str:
    """The window as the user gave it, in the options' own words."""
    parts = ([] if start is None else [f"--start {start:g}"]) + ([] if end is None else [f"--end {end:g}"])
    return " ".join(parts)


def check_order(start: float | None, end: float | None) -> None:
    """Before any file is read: an end at or before the start is no window."""
    if start is not None and end is not None and end <= start:
        raise UsageError(
            f"{describe(start, end)}: the window ends before it starts (both are seconds of the "
            "recording's t column); give an --end greater than --start"
        )


@dataclass(frozen=True)
class Window:
    """The rows a window kept: what was asked and what it got."""

    start_s: float | None  # as asked (None: from the first row)
    end_s: float | None  # as asked (None: to the last row)
    t_first_s: float  # t of the first row kept
    t_last_s: float  # t of the last row kept
    rows: int
    rows_in_file: int
    note: str | None = None  # a bound past the data's edge, clipped

    def as_json(self) -> dict[str, Any]:
        return {
            "start_s": self.start_s,
            "end_s": self.end_s,
            "t_first_s": self.t_first_s,
            "t_last_s": self.t_last_s,
            "rows": self.rows,
            "rows_in_file": self.rows_in_file,
        }

    def line(self) -> str:
        """One line for the human output and the report."""
        return (
            f"window analysed: t = {self.t_first_s:g} to {self.t_last_s:g} s "
            f"({self.rows} of {self.rows_in_file} rows; {describe(self.start_s, self.end_s)})"
        )


def cut(d: Dataset, start: float | None, end: float | None) -> tuple[Dataset, Window]:
    """The rows of `d` with start ≤ t ≤ end, and what the window kept; bad windows refused."""
    check_order(start, end)
    where, asked = d.path or d.name, describe(start, end)
    t = d.t
    n, t0, t1 = len(t), float(t[0]), float(t[-1])
    span = f"this file's t runs from {t0:g} to {t1:g} s"
    lo = 0 if start is None else int(np.searchsorted(t, start, side="left"))
    hi = n if end is None else int(np.searchsorted(t, end, side="right"))
    if hi <= lo:  # t increases strictly (the reader checks it): no row between the bounds
        raise DataFileError(
            f"{where}: the window {asked} holds no rows: {span}; "
            "give --start/--end inside it (seconds of the file's t column, not of the run's clock)"
        )
    kept = hi - lo
    seconds = float(t[hi - 1] - t[lo])
    if kept < MIN_ROWS or seconds < MIN_SECONDS:
        raise DataFileError(
            f"{where}: the window {asked} keeps {kept} rows ({seconds:.3g} s); the doctor needs at "
            f"least {MIN_ROWS} rows and {MIN_SECONDS:g} s: widen the window ({span})"
        )
    past = []
    if start is not None and start < t0:
        past.append(f"--start {start:g} is before the first row (t = {t0:g} s)")
    if end is not None and end > t1:
        past.append(f"--end {end:g} is past the last row (t = {t1:g} s)")
    note = f"{where}: {' and '.join(past)}: the window is clipped to the data" if past else None
    window = Window(start, end, float(t[lo]), float(t[hi - 1]), kept, n, note)
    if kept == n:
        return d, window
    return d.slice(lo, hi, f" [t {window.t_first_s:g}-{window.t_last_s:g} s]"), window
