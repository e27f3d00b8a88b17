"""A recording's loop channel as one uniform table: what `tvsctl export` writes, in any format.

Reading only — no file is written here (`tvsd.cli.export` picks the writer). `loop_table` turns a
`RecordingFile` into a `Table`:
- the rows on a uniform time grid (the loop channel's 1 ms bins): a stall of the daemon that left
  no bins (2–195 ms under load) becomes rows filled by linear interpolation, flagged ``gap = 1``,
  and listed in `Table.gaps` (with `strict`, a gap is refused as before: DataFileError);
  a bin that came again (t stepping back: recordings made before ticks moved by number) is
  dropped and counted;
- the controller's reference joined by bin: ``omega_ref``, ``phi_ref`` and ``u_ff`` from the
  ``reference`` channel (docs/architecture.md: the doctor's instruments in closed loop);
- the fault marks placed on the grid: ``fault`` counts the faults marked in each sample, and
  `Table.faults` lists them (time, kind, cause).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tvsd.errors import DataFileError, UsageError
from tvsd.recording.reader import RecordingFile

REFERENCE_CHANNEL = "reference"
REFERENCE_COLUMNS = ("omega_ref", "phi_ref", "u_ff")
JITTER = 0.01  # a sample more than 1 % of a period off the grid means the channel is not uniform


@dataclass(frozen=True)
class Gap:
    t_s: float  # the last sample before the gap, s after the first exported sample
    samples: int  # samples missing (filled and flagged)
    period_s: float

    @property
    def duration_ms(self) -> float:
        return self.samples * self.period_s * 1e3


@dataclass(frozen=True)
class FaultMark:
    t_s: float  # s after the first exported sample
    kind: str
    cause: str


@dataclass
class Table:
    t: np.ndarray  # s after the first exported sample, uniform
    rate_hz: float
    columns: dict[str, np.ndarray]  # u, omega, [phi], reference, gap, fault, the channel's others
    meta: dict[str, object] = field(default_factory=dict)
    gaps: list[Gap] = field(default_factory=list)
    faults: list[FaultMark] = field(default_factory=list)
    duplicates: int = 0  # rows dropped because their bin came twice
    unplaced_faults: int = 0  # fault marks without loop time (older recordings) or outside the span

    @property
    def missing_samples(self) -> int:
        return sum(g.samples for g in self.gaps)


def loop_table(
    rec: RecordingFile, channel: str, start: float = 0.0, end: float = math.inf, *, strict: bool = False
) -> Table:
    """The channel's rows from `start` to `end` s after its first sample, as a uniform `Table`."""
    if channel not in rec.channels:
        have = ", ".join(sorted(rec.channels)) or "none"
        raise DataFileError(f"{rec.path}: no '{channel}' channel in this recording (channels: {have})")
    rows = rec.channels[channel]
    fields = rows.dtype.names or ()
    missing = [f for f in ("t", "u", "omega") if f not in fields]
    if missing:
        raise DataFileError(f"{rec.path}: channel '{channel}' lacks field(s) {', '.join(missing)}")
    if len(rows) < 2:
        raise DataFileError(f"{rec.path}: channel '{channel}' has {len(rows)} row(s); need at least 2")
    t_abs = rows["t"].astype(float)
    rel = t_abs - t_abs[0]
    sel = rows[(rel >= start) & (rel <= end)]
    if len(sel) < 2:
        raise UsageError(f"--start {start:g} / --end {end:g} keep {len(sel)} row(s); need at least 2")
    period, k, keep = _grid(sel["t"].astype(float), rec, strict)
    sel, k = sel[keep], k[keep]
    n = int(k[-1]) + 1
    t0 = float(sel["t"][0])
    numeric = [f for f in fields if f != "t" and sel.dtype[f].shape == () and sel.dtype[f].kind in "fiub"]
    columns = {f: _fill(k, sel[f].astype(float), n) for f in numeric}
    ref = rec.channels.get(REFERENCE_CHANNEL)
    if ref is not None and channel == "loop" and len(ref):
        columns.update(_reference(ref, t0, period, n))
    gap = np.ones(n)
    gap[k] = 0.0
    columns["gap"] = gap
    table = Table(np.arange(n) * period, 1.0 / period, columns, duplicates=int(np.sum(~keep)))
    table.gaps = _gaps(k, period)
    table.meta["start_s"] = float(sel["t"][0] - t_abs[0])
    _place_faults(table, rec.marks, t0, period)
    return table


def _grid(t: np.ndarray, rec: RecordingFile, strict: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """The period, each row's sample number on the grid, and which rows to keep (not a repeat)."""
    dt = np.diff(t)
    pos = dt[dt > 0]
    period = float(np.median(pos)) if len(pos) else 0.0
    if not period > 0:
        raise DataFileError(f"{rec.path}: t does not increase (median step {period:g} s)")
    k = np.rint((t - t[0]) / period).astype(np.int64)
    off = np.abs(t - t[0] - k * period) > JITTER * period
    if np.any(off):
        j = int(np.argmax(off))
        raise DataFileError(
            f"{rec.path}: t = {t[j] - t[0]:.6f} s is off the {period:g} s grid: this channel is not "
            "uniformly sampled, so it cannot be exported as a recording CSV"
        )
    # A bin at or before one already seen is a repeat (the old drain re-sent ticks, so t stepped
    # back and ran over bins again): kept once, the first time.
    keep = np.concatenate([[True], k[1:] > np.maximum.accumulate(k)[:-1]])
    if strict:
        jumps = np.nonzero(np.diff(k[keep]) > 1)[0]
        if len(jumps):
            j = int(jumps[0])
            kk, tt = k[keep], t[keep]
            raise DataFileError(
                f"{rec.path}: t jumps by {(kk[j + 1] - kk[j]) * period:g} s at t = {tt[j] - t[0]:.4f} s "
                f"after the first sample (step {period:g} s elsewhere): {kk[j + 1] - kk[j] - 1} samples "
                "missing (dropped by the recorder, or the loop stopped); export around it with "
                "--start/--end, or without --strict to fill and flag the gaps"
            )
    return period, k, keep


def _fill(k: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Values on the full grid 0..n-1: known at samples k, linear in between (the gaps)."""
    return np.interp(np.arange(n), k, values)


def _reference(ref: np.ndarray, t0: float, period: float, n: int) -> dict[str, np.ndarray]:
    """The reference channel's columns on the loop's grid, joined by bin (the same 1 ms bins)."""
    names = ref.dtype.names or ()
    kr = np.rint((ref["t"].astype(float) - t0) / period).astype(np.int64)
    order = np.argsort(kr, kind="stable")
    kr, ref = kr[order], ref[order]
    first = np.concatenate([[True], np.diff(kr) > 0])
    kr, ref = kr[first], ref[first]
    inside = (kr >= 0) & (kr < n)
    if np.sum(inside) < 2:
        return {}
    kr, ref = kr[inside], ref[inside]
    return {c: _fill(kr, ref[c].astype(float), n) for c in REFERENCE_COLUMNS if c in names}


def _gaps(k: np.ndarray, period: float) -> list[Gap]:
    jumps = np.nonzero(np.diff(k) > 1)[0]
    return [Gap(float(k[j] * period), int(k[j + 1] - k[j] - 1), period) for j in jumps]


def _place_faults(table: Table, marks: list[dict[str, Any]], t0: float, period: float) -> None:
    """Fault marks on the grid, by their loop time (`t_loop`, the control thread's clock)."""
    n = len(table.t)
    fault = np.zeros(n)
    for m in marks:
        if m.get("event") != "fault":
            continue
        t_loop = m.get("t_loop")
        k = round((float(t_loop) - t0) / period) if isinstance(t_loop, (int, float)) else -1
        if not 0 <= k < n:
            table.unplaced_faults += 1
            continue
        fault[k] += 1
        cause = " ".join(str(m.get("cause", "")).split())
        table.faults.append(FaultMark(k * period, str(m.get("kind", "")), cause))
    table.columns["fault"] = fault
