"""`tvsctl export REC --csv OUT`: a daemon recording's loop channel as docs/architecture.md's recording CSV.

Reading and writing are apart: `tvsd.recording.table.loop_table` makes the uniform table (gaps
filled and flagged, the controller's reference joined, fault marks placed), and a writer of
`WRITERS` puts it in a file — another format is one more writer.

Columns: t, u, omega, phi, then omega_ref, phi_ref, u_ff (the daemon's reference), u_exc (the
voltage `tvsctl identify` added after the law, from the recording's `excitation` channel: the
doctor's instrument; 0 outside the run; only when the recording holds one), u_law (the control
law's command, the 1 ms mean of its 10 kHz ticks, when `u` is from the `pwm` channel: the frames
the daemon sent, held, averaged per sample, which is what the drive was told to apply), omega_loop
(the control thread's speed measurement, when omega and phi come from the recording's `states`
channel: the MCU's encoder frames at their sampling instants, tvsd/cli/export_states.py), gap (1: a
sample the recording lacked, filled by linear interpolation), fault (faults marked in that sample),
and any other numeric field of the channel. Metadata lines: the source, ``u_unit: V`` (the daemon
commands volts), the gaps (how many, the missing samples, the first ones listed), the faults (one
line each: time, kind, cause), and the scalar settings of the config the daemon ran with (plant,
drive, control, geometry). `--strict` refuses a recording with a gap, as export used to.
`tvsctl analyze OUT` reads the result.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.cli.export_states import OMEGA_SOURCE, frame_timing, from_states
from tvsd.cli.output import warn
from tvsd.errors import EXIT_OK, UsageError
from tvsd.recording.csvfile import format_lines, write
from tvsd.recording.format import LOOP_CHANNEL
from tvsd.recording.reader import flatten_config, open_recording
from tvsd.recording.table import Table, loop_table

CONFIG_SECTIONS = ("plant", "drive", "control", "geometry")
FORMATS = ("csv", "parquet", "mcap")
SIGNIFICANT_DIGITS = 9  # tvsd.recording.csvfile.write keeps %.9g
LISTED_GAPS = 50  # gaps listed one by one in the metadata; more are only counted
U_UNIT = "V"  # the daemon's command is the drive voltage (docs/architecture.md, u_unit)
# Both u's (the frames sent, sent_column; the law's, loop channel) are means over the bin that
# ends at the row's time, as omega is (the frames' angle difference over it, export_states):
# tvsd's convention, so the doctor's delay on an export is against it, not a sample unsure.
U_SAMPLING = "mean"
EXCITATION_CHANNEL = "excitation"  # what identify played (tvsd/daemon/session_recording.py)
U_EXC = "u_exc"  # its voltage, per sample: the doctor's instrument in closed loop
STATES_CHANNEL = "states"  # the MCU's encoder frames (tvsd/daemon/session_recording.py)
OMEGA_LOOP = "omega_loop"  # the control thread's speed measurement (omega before the states channel)
PWM_CHANNEL = "pwm"  # the PWM frames the daemon sent (tvsd/daemon/session_recording.py)
U_SOURCE = "the PWM frames sent to the drive, held (u_law: the control law's 1 ms mean)"
U_LAW = "u_law"  # the control law's command, the 1 ms mean of its ticks (u before the pwm channel)


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "export",
        help="write a daemon recording's loop signals as the recording CSV (input of analyze)",
        description="Write the loop channel (t,u,omega,phi) of a recording made by tvsd as the "
        "recording CSV of docs/architecture.md, with the controller's reference (omega_ref, "
        "phi_ref), gaps filled and flagged (gap column), fault marks (fault column) and the "
        "daemon's config as metadata lines.",
    )
    p.add_argument("rec", type=Path, metavar="REC", help="recording directory written by tvsd")
    p.add_argument("--csv", type=Path, metavar="OUT", help="CSV file to write (= --format csv --out OUT)")
    p.add_argument("--out", type=Path, metavar="OUT", help="file to write, in --format")
    p.add_argument(
        "--format",
        choices=FORMATS,
        default="csv",
        help="csv: the recording CSV (analyze reads it); parquet: the same table for pandas/polars; "
        "mcap: every channel and the marks, JSON schemas per channel (Foxglove)",
    )
    p.add_argument("--channel", default=LOOP_CHANNEL, help=f"channel to export (default: {LOOP_CHANNEL})")
    p.add_argument("--start", type=float, default=0.0, metavar="S", help="seconds after the first sample")
    p.add_argument("--end", type=float, default=math.inf, metavar="S", help="seconds after the first sample")
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse a recording with missing samples (default: fill them by interpolation, flag "
        "them in the gap column and list them)",
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if (args.csv is None) == (args.out is None) or (args.csv is not None and args.format != "csv"):
        raise UsageError("export: give --out OUT (with --format csv|parquet|mcap), or --csv OUT")
    out: Path = args.csv if args.csv is not None else args.out
    rec = open_recording(args.rec)  # first: it says why a recording cannot be read
    _outside_the_recording(out, Path(args.rec))
    for problem in rec.problems:
        warn(f"{args.rec}: {problem}")
    if args.format == "mcap":  # every channel and the marks, not the loop table
        from tvsd.cli.export_formats import export_mcap

        return export_mcap(rec, args.rec, out)
    table = loop_table(rec, args.channel, args.start, args.end, strict=args.strict)
    sent = args.channel == LOOP_CHANNEL and len(rec.channels.get(PWM_CHANNEL, ())) > 0
    if sent:
        t_first = float(rec.channels[args.channel]["t"][0]) + float(table.meta["start_s"])  # type: ignore[arg-type]
        table.columns[U_LAW] = table.columns["u"]
        table.columns["u"] = sent_column(rec.channels[PWM_CHANNEL], t_first, table, table.columns[U_LAW])
    measured, frames = None, None
    if args.channel == LOOP_CHANNEL and len(rec.channels.get(STATES_CHANNEL, ())) > 1:
        t_first = float(rec.channels[args.channel]["t"][0]) + float(table.meta["start_s"])  # type: ignore[arg-type]
        cols = table.columns
        measured = from_states(
            rec.channels[STATES_CHANNEL],
            t_first,
            len(table.t),
            1.0 / table.rate_hz,
            cols["omega"],
            cols["phi"],
        )
        if measured is not None:
            cols[OMEGA_LOOP] = cols["omega"]
            cols["omega"], cols["phi"], _ = measured
            frames = frame_timing(rec.channels[STATES_CHANNEL], t_first, 1.0 / table.rate_hz)
    if args.channel == LOOP_CHANNEL and EXCITATION_CHANNEL in rec.channels:
        t_first = float(rec.channels[args.channel]["t"][0]) + float(table.meta["start_s"])  # type: ignore[arg-type]
        rows = played(rec.channels[EXCITATION_CHANNEL], rec.marks)
        table.columns[U_EXC] = excitation_column(rows, t_first, table)
    span = float(table.t[-1])
    span_ok = 10.0 ** (math.ceil(math.log10(max(span, 1e-300))) - SIGNIFICANT_DIGITS) <= 0.005 / table.rate_hz
    if not span_ok:
        raise UsageError(
            f"{span:.0f} s at {table.rate_hz:g} Hz is too long for the CSV's {SIGNIFICANT_DIGITS} digits "
            "of t; export it in parts with --start/--end"
        )
    meta: dict[str, object] = {
        "source": "tvsctl export",
        "recording": args.rec.resolve(),
        "started_utc": rec.header.get("started_utc", "unknown"),
        "channel": args.channel,
        "u_unit": U_UNIT,
        **({"u_sampling": U_SAMPLING} if args.channel == LOOP_CHANNEL else {}),
        **(
            {"u_source": "the PWM frames sent to the drive, held (u_law: the control law's mean)"}
            if sent
            else {}
        ),
        **(
            {"omega_source": OMEGA_SOURCE, "omega_from_frames": f"{measured[2]} of {len(table.t)} samples"}
            if measured is not None
            else {}
        ),
        **(encoder_meta(rec.config_text, frames) if args.channel == LOOP_CHANNEL else {}),
        **table.meta,
    }
    if rec.stats is not None:
        meta["dropped_rows"] = rec.stats.get("channels", {}).get(args.channel, {}).get("dropped_rows", 0)
    lines = declared_lines(rec.marks) if args.channel == LOOP_CHANNEL else ()
    if lines:  # identify's multisine lines: the doctor leaves them out of its resonance scan
        meta["excitation_hz"] = format_lines(lines)
    meta.update(_gap_meta(table))
    meta.update(_fault_meta(table))
    meta.update(flatten_config(rec.config_text, CONFIG_SECTIONS))
    WRITERS[args.format](out, table, meta)
    if table.gaps:
        warn(
            f"{args.rec}: {len(table.gaps)} gap(s), {table.missing_samples} sample(s) missing "
            f"(longest {max(g.duration_ms for g in table.gaps):g} ms): filled by interpolation, "
            "flagged gap=1 (--strict refuses them)"
        )
    print(f"{out}: {len(table.t)} rows, {span:.3f} s at {table.rate_hz:g} Hz from {args.rec}")
    return EXIT_OK


def _outside_the_recording(out: Path, rec: Path) -> None:
    """`--csv REC/seg-00000.tvsrec` replaced the recording with its own CSV, and any seg-*.tvsrec
    name written inside REC made it unreadable: the recording is read-only to export."""
    target = out.resolve()
    if target == rec.resolve() or (rec.is_dir() and rec.resolve() in target.parents):
        where = "is the recording" if target == rec.resolve() else "is inside the recording"
        raise UsageError(f"{out} {where} {rec}: writing there would overwrite or corrupt it; write elsewhere")


def encoder_meta(config_text: str, frames: tuple[float, float] | None) -> dict[str, object]:
    """The encoder the angle was read with: its counts per revolution (the daemon's `mcu` config,
    else the setting's default, which the daemon then ran with) and, where omega and phi are
    interpolated between its frames, their rate and offset after the sample edges — what the
    model doctor needs for the quantisation floor of an interpolated angle (tvsd.analysis.quantisation)."""
    from tvsd.hw.mcu.settings import McuSettings

    counts = flatten_config(config_text, ("mcu",)).get("mcu.encoder_counts_per_rev")
    meta: dict[str, object] = {"encoder_counts_per_rev": counts or McuSettings().encoder_counts_per_rev}
    if frames is not None:
        meta["encoder_frame_hz"] = f"{frames[0]:.9g}"
        meta["encoder_frame_offset_s"] = f"{frames[1]:.6g}"
    return meta


def _gap_meta(table: Table) -> dict[str, object]:
    meta: dict[str, object] = {"gaps": len(table.gaps), "gap_samples": table.missing_samples}
    for j, g in enumerate(table.gaps[:LISTED_GAPS], 1):
        meta[f"gap_{j}"] = f"after t={g.t_s:.3f} s, {g.samples} samples ({g.duration_ms:g} ms)"
    if table.duplicates:
        meta["duplicate_rows_dropped"] = table.duplicates
    return meta


def _fault_meta(table: Table) -> dict[str, object]:
    meta: dict[str, object] = {"faults": len(table.faults)}
    for j, f in enumerate(table.faults, 1):
        meta[f"fault_{j}"] = f"t={f.t_s:.3f} s, {f.kind}: {f.cause}"
    if table.unplaced_faults:
        meta["faults_not_placed"] = table.unplaced_faults  # older recordings' marks lack loop time
    return meta


def write_csv(path: Path, table: Table, meta: dict[str, object]) -> None:
    cols = dict(table.columns)
    u, omega, phi = cols.pop("u"), cols.pop("omega"), cols.pop("phi", None)
    order = ("omega_ref", "phi_ref", "u_ff", U_EXC, U_LAW, OMEGA_LOOP, "gap", "fault")
    extra = {name: cols.pop(name) for name in order if name in cols}
    extra.update(cols)
    write(path, table.t, u, omega, phi, table.rate_hz, meta, {k: np.asarray(v) for k, v in extra.items()})


def declared_lines(marks: list[dict[str, Any]]) -> tuple[float, ...]:
    """The multisine frequencies (Hz) of every identify run in the recording (its start marks'
    `lines_hz`), sorted: the recording CSV's `# excitation_hz:`."""
    found = {float(f) for m in marks if m.get("event") == "identify_start" for f in m.get("lines_hz") or ()}
    return tuple(sorted(found))


def played(rows: np.ndarray, marks: list[dict[str, Any]]) -> np.ndarray:
    """The excitation rows the control thread played: identify writes its whole table at the
    start, so the rows of an aborted run after its `identify_end` mark (up to the next run's
    start) were never played."""
    starts = sorted(float(m["t0"]) for m in marks if m.get("event") == "identify_start" and "t0" in m)
    keep = np.ones(len(rows), dtype=bool)
    for m in marks:
        t_end = m.get("t_loop")
        if m.get("event") != "identify_end" or m.get("outcome") != "aborted" or t_end is None:
            continue
        nxt = next((t for t in starts if t > float(t_end)), math.inf)
        keep &= ~((rows["t"] >= float(t_end)) & (rows["t"] < nxt))
    return rows[keep]


def excitation_column(rows: np.ndarray, t_first: float, table: Table) -> np.ndarray:
    """identify's voltage excitation averaged over each loop sample (the loop's bins end at their
    t and last one period, as u is averaged): the exact mean of the played step function (each
    row held `period` from its t, nothing outside the rows), 0 where identify did not play."""
    period = 1.0 / table.rate_hz
    edges = t_first - period + np.arange(len(table.t) + 1) * period
    if len(rows) == 0:
        return np.zeros(len(table.t))
    order = np.argsort(rows["t"], kind="stable")
    t, v = rows["t"][order].astype(float), rows["d_volts"][order].astype(float)
    held = np.median(np.diff(t)) if len(t) > 1 else period
    end = np.minimum(t + held, np.append(t[1:], np.inf))  # a row lasts until the next one, at most `held`
    area = np.cumsum(v * (end - t))
    knots = np.column_stack([t, end]).ravel()
    integral = np.column_stack([np.concatenate([[0.0], area[:-1]]), area]).ravel()
    cum = np.interp(edges, knots, integral, left=0.0, right=float(area[-1]))
    return np.diff(cum) / period


def sent_column(rows: np.ndarray, t_first: float, table: Table, law: np.ndarray) -> np.ndarray:
    """The volts the daemon's PWM frames told the drive, averaged over each loop sample: each
    frame's held from its sending until the next (the MCU holds a duty until the next frame),
    the exact mean of that step function over the sample's 1 ms bin. The law's command (`law`)
    where the bin began before the first frame recorded.

    Why not the law's 1 ms mean: the drive applies the frames, sent once per batch of states
    (2 kHz on the ATmega, each millisecond through the SIL's pty, irregularly when the daemon's
    I/O thread runs late), not the 10 kHz ticks the bins average (docs/measurements/doctor-method.md,
    step 8)."""
    period = 1.0 / table.rate_hz
    edges = t_first - period + np.arange(len(table.t) + 1) * period
    order = np.argsort(rows["t"], kind="stable")
    t, v = rows["t"][order].astype(float), rows["volts"][order].astype(float)
    area = np.concatenate([[0.0], np.cumsum(v[:-1] * np.diff(t))])  # ∫ from t[0] to t[i]
    i = np.searchsorted(t, edges, side="right") - 1
    j = np.maximum(i, 0)
    integral = np.where(i >= 0, area[j] + v[j] * (edges - t[j]), 0.0)
    out = np.diff(integral) / period
    return np.where(edges[:-1] >= t[0], out, law)


def write_parquet(path: Path, table: Table, meta: dict[str, object]) -> None:
    from tvsd.cli.export_formats import export_parquet  # pyarrow: imported only for this format

    export_parquet(path, table, meta)


# Output formats by name: a writer takes the path, the table and the metadata lines (mcap, which
# carries every channel and the marks rather than the loop table, is handled before the table).
WRITERS: dict[str, Callable[[Path, Table, dict[str, object]], None]] = {
    "csv": write_csv,
    "parquet": write_parquet,
}
