"""`tvsctl analyze FILE`: the model doctor (the contract in docs/architecture.md)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

from tvsd.cli import argtypes
from tvsd.cli.output import fmt, print_json, print_table, warn
from tvsd.config import load_config
from tvsd.errors import EXIT_OK, UsageError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "analyze",
        help="model doctor: what the paper's model gets wrong in a recording, and why",
        description="Fit the paper's model to a recording (CSV contract or EMPS .mat), find what it "
        "misses, name the cause, extend the model and measure the gain on data not used for fitting. "
        "--start/--end analyse a window of it (seconds of its t column): cut a warm-up or a shutdown.",
    )
    p.add_argument("file", type=Path, help="recording CSV (docs/architecture.md) or EMPS .mat file")
    p.add_argument(
        "--heldout", type=Path, metavar="FILE", help="judge on this recording (default: last third)"
    )
    p.add_argument(
        "--start",
        type=argtypes.seconds,
        metavar="S",
        help="analyse only rows with t >= S (seconds of the file's t column): cut a warm-up",
    )
    p.add_argument(
        "--end",
        type=argtypes.seconds,
        metavar="E",
        help="analyse only rows with t <= E: cut a shutdown (the --heldout file is judged whole)",
    )
    p.add_argument("--json", action="store_true", help="print the JSON object of docs/architecture.md")
    p.add_argument("--report", type=Path, metavar="DIR", help="write report.md and figures into DIR")
    p.add_argument("--config", type=Path, help="scanner config for R, L, kM, ku (default: config/tvsd.yaml)")
    p.add_argument("--params", choices=("default", "paper"), default="default")
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no progress lines on stderr (there are none when stderr is not a terminal)",
    )
    p.add_argument(
        "--seed",
        type=argtypes.seed,
        default=0,
        help="seed of the bootstrap that calibrates the decision",
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from tvsd.analysis import memory
    from tvsd.analysis import report as R
    from tvsd.analysis.dataset import check_heldout, load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.noise import COLOUR_P
    from tvsd.analysis.prep import EMPS_BAND, Band, check_filled
    from tvsd.analysis.summary import as_json
    from tvsd.analysis.window import check_order, cut

    cfg = load_config(args.config) if args.config else load_config(params=args.params)
    start = time.monotonic()

    from tvsd.cli.progress import on_terminal

    show = on_terminal() and not args.quiet  # a pipe or a log gets the result only

    def progress(message: str) -> None:
        if show:
            print(f"[{time.monotonic() - start:5.1f} s] {message}", file=sys.stderr, flush=True)

    check_order(args.start, args.end)  # before the file is read
    if args.report:
        _check_report_dir(args.report)  # before the analysis's seconds, not after them
    data = load(args.file, cfg)
    window = None
    if args.start is not None or args.end is not None:
        data, window = cut(data, args.start, args.end)
        if window.note:
            warn(window.note)
    heldout = load(args.heldout, cfg) if args.heldout else None
    if heldout is not None:
        check_heldout(data, heldout)
    band = EMPS_BAND if data.units.axis == "linear" else Band()
    for dataset in (data, heldout):  # refused in one line where the doctor would not fit in memory
        if dataset is not None:
            memory.check(dataset, band)
    for dataset in (data, heldout):  # gap-filled rows (tvsctl export's `gap` column)
        note = None if dataset is None else check_filled(dataset, band)
        if note is not None:
            warn(note)
    dg = diagnose(data, cfg.plant.v0, heldout=heldout, band=band, progress=progress, seed=args.seed)
    summary = as_json(dg)
    if window is not None:  # before the report, which states it too
        summary["window"] = window.as_json()
    if args.report:
        progress("writing the report")
        try:
            page = R.write(dg, summary, args.report)
        except OSError as exc:  # a full disk, a folder made read-only meanwhile
            raise UsageError(f"--report {args.report}: cannot write the report: {exc.strerror}") from exc
        summary["report"] = str(page)
    if args.json:
        print_json(summary)
        return EXIT_OK
    if window is not None:
        print(window.line())
    print(summary["summary"])
    print()
    if len(summary["causes"]) > 1:
        print("causes named, best first (each tested against the model holding those above it):")
        for c in summary["causes"]:
            print(f"  {c['step']}. {cause_line(c)}")
        print()
    print_table(
        [
            (
                c["cause"],
                f"{c['score']:.1f}",
                f"{c['p_value']:.3g}",
                "yes" if c["significant"] else "no",
                c["why_not"]["code"] if "why_not" in c else "",
            )
            for c in summary["candidates"]
        ],
        ["candidate", "z (own null)", "p (alone)", "named", "why not"],
    )
    dec = summary["decision"]
    print(f"named above z = {dec['threshold']:.2f} (false-alarm rate {dec['alpha']:g})")
    for c in summary["candidates"]:
        # the footnotes the summary sentence names: above the gate, or coloured past its own test
        colour_low = c["cause"] != "colored_noise" or c["p_value"] < COLOUR_P
        if "why_not" in c and c["why_not"]["code"] != "below_gate" and colour_low:
            print(f"  {c['cause']} not named: {c['why_not']['reason']}")
    print()
    print(
        f"held-out speed RMSE: paper's model {dg.heldout_rmse_base:.4g}, extended {dg.heldout_rmse_ext:.4g} "
        f"{data.units.speed} (gain {dg.gain_pct:.1f} %)"
    )
    if args.report:
        print(f"report: {summary['report']}")
    return EXIT_OK


def _check_report_dir(out: Path) -> None:
    """--report DIR: an existing folder, or a new one in an existing folder, that this user may
    write (as tvsd's --data-dir: no missing parents made on the way)."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"--report {out}: exists and is not a folder; give a folder for report.md")
    target = out if out.exists() else out.parent
    if not target.is_dir():
        raise UsageError(f"--report {out}: folder {target} does not exist; create it first")
    if not os.access(target, os.W_OK | os.X_OK):
        raise UsageError(f"--report {out}: {target} is not writable by this user; give another folder")


def cause_line(c: dict[str, Any]) -> str:
    """One named cause: its name, parameters, statistic against its step's gate, and gain."""
    params = ", ".join(f"{k}={fmt(v)}" for k, v in c["effect"].items())
    return (
        f"{c['cause']} ({params}): z {fmt(c['score'])} > {fmt(c['threshold'])}, "
        f"out-of-sample gain {fmt(c['cv_gain'])} noise variances"
    )
