"""`tvsctl export REC --csv OUT`: a daemon recording's loop channel as docs/architecture.md's recording CSV.

t, u, omega, phi (and any other fields of the loop channel, as extra columns) come from the `loop`
channel; the metadata lines name the source and carry the scalar settings of the config the daemon
ran with (plant, drive, control, geometry). `tvsctl analyze OUT` reads the result.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from tvsd.cli.output import warn
from tvsd.errors import EXIT_OK, DataFileError, UsageError
from tvsd.recording.csvfile import write
from tvsd.recording.format import LOOP_CHANNEL
from tvsd.recording.reader import flatten_config, open_recording

CONFIG_SECTIONS = ("plant", "drive", "control", "geometry")
FORMATS = ("csv", "parquet", "mcap")
SIGNIFICANT_DIGITS = 9  # tvsd.recording.csvfile.write keeps %.9g


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "export",
        help="write a daemon recording's loop signals as the recording CSV (input of analyze)",
        description="Write the loop channel (t,u,omega,phi) of a recording made by tvsd as the "
        "recording CSV of docs/architecture.md, with the daemon's config as metadata lines.",
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
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if (args.csv is None) == (args.out is None) or (args.csv is not None and args.format != "csv"):
        raise UsageError("export: give --out OUT (with --format csv|parquet|mcap), or --csv OUT")
    out: Path = args.csv if args.csv is not None else args.out
    rec = open_recording(args.rec)
    for problem in rec.problems:
        warn(f"{args.rec}: {problem}")
    if args.format == "mcap":
        from tvsd.cli.export_formats import export_mcap

        return export_mcap(rec, args.rec, out)
    if args.channel not in rec.channels:
        have = ", ".join(sorted(rec.channels)) or "none"
        raise DataFileError(f"{args.rec}: no '{args.channel}' channel in this recording (channels: {have})")
    rows = rec.channels[args.channel]
    fields = rows.dtype.names or ()
    missing = [f for f in ("t", "u", "omega") if f not in fields]
    if missing:
        raise DataFileError(f"{args.rec}: channel '{args.channel}' lacks field(s) {', '.join(missing)}")
    t_all = rows["t"].astype(float)
    if len(t_all) < 2:
        raise DataFileError(f"{args.rec}: channel '{args.channel}' has {len(t_all)} row(s); need at least 2")
    rel = t_all - t_all[0]
    sel = rows[(rel >= args.start) & (rel <= args.end)]
    if len(sel) < 2:
        raise UsageError(
            f"--start {args.start:g} / --end {args.end:g} keep {len(sel)} row(s); need at least 2"
        )
    t = sel["t"].astype(float)
    rate = _uniform_rate(t, args.rec)
    t = t - t[0]  # relative time: %.9g of a monotonic clock's seconds would lose the sample spacing
    span_ok = 10.0 ** (math.ceil(math.log10(max(t[-1], 1e-300))) - SIGNIFICANT_DIGITS) <= 0.005 / rate
    if not span_ok:
        raise UsageError(
            f"{t[-1]:.0f} s at {rate:g} Hz is too long for the CSV's {SIGNIFICANT_DIGITS} digits of t; "
            "export it in parts with --start/--end"
        )
    extra = {
        f: sel[f].astype(float)
        for f in fields
        if f not in ("t", "u", "omega", "phi") and sel.dtype[f].shape == () and sel.dtype[f].kind in "fiub"
    }
    meta: dict[str, object] = {
        "source": "tvsctl export",
        "recording": args.rec.resolve(),
        "started_utc": rec.header.get("started_utc", "unknown"),
        "channel": args.channel,
        "start_s": float(rel[(rel >= args.start)][0]),
    }
    if rec.stats is not None:
        meta["dropped_rows"] = rec.stats.get("channels", {}).get(args.channel, {}).get("dropped_rows", 0)
    meta.update(flatten_config(rec.config_text, CONFIG_SECTIONS))
    phi = sel["phi"].astype(float) if "phi" in fields else None
    if args.format == "parquet":
        from tvsd.cli.export_formats import export_parquet

        export_parquet(out, t, sel["u"].astype(float), sel["omega"].astype(float), phi, rate, meta, extra)
    else:
        write(out, t, sel["u"].astype(float), sel["omega"].astype(float), phi, rate, meta, extra)
    print(f"{out}: {len(t)} rows, {t[-1]:.3f} s at {rate:g} Hz from {args.rec}")
    return EXIT_OK


def _uniform_rate(t: np.ndarray, rec: Path) -> float:
    """The sample rate, if t is strictly increasing and uniform (the CSV contract's 1 % rule)."""
    dt = np.diff(t)
    period = float(np.median(dt))
    if not period > 0:
        raise DataFileError(f"{rec}: t does not increase (median step {period:g} s)")
    bad = np.nonzero((dt <= 0) | (np.abs(dt - period) > 0.01 * period))[0]
    if len(bad):
        k = int(bad[0])
        raise DataFileError(
            f"{rec}: t jumps by {dt[k]:g} s at t = {t[k] - t[0]:.4f} s after the first sample "
            f"(step {period:g} s elsewhere): about {round(dt[k] / period) - 1} samples missing "
            "(dropped by the recorder, or the loop stopped); export around it with --start/--end"
        )
    return 1.0 / period
