"""`tvsctl latency`: the machine's wake-up floor beside the 10 kHz control loop, in one run.

Offline (no daemon): the floor is a bare absolute-deadline sleep loop (half before, half after);
the loop is the control kernel with the SIL plant spinning at 25 rev/s. Same clock, period and
thread setup (SCHED_FIFO, one CPU, mlockall when permitted), like LinuxCNC's latency-test.
"""

from __future__ import annotations

import argparse
from typing import Any

from tvsd.cli.output import print_json, print_table
from tvsd.errors import EXIT_OK, UsageError

_DECADES = ("<1 µs", "1–10 µs", "10–100 µs", "0.1–1 ms", "1–10 ms", "≥10 ms")


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("latency", help="wake-up jitter of the control loop vs the machine's floor")
    p.add_argument("--seconds", type=float, default=10.0, help="length of each measurement (default 10)")
    p.add_argument("--no-realtime", action="store_true", help="do not ask for SCHED_FIFO/affinity/mlock")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from tvsd.control.latency import compare

    if not 0.01 <= args.seconds <= 3600:
        raise UsageError(f"--seconds {args.seconds}: use 0.01 … 3600")
    res = compare(args.seconds, realtime=not args.no_realtime)
    if args.json:
        print_json(res)
    else:
        _print(res)
    return EXIT_OK


def _print(res: dict[str, Any]) -> None:
    keys = ("p50_us", "p99_us", "p999_us", "max_us", "missed_ticks", "rate_hz", "cpu_per_tick_us")
    heads = ("", "p50 µs", "p99 µs", "p99.9 µs", "max µs", "missed", "rate Hz", "CPU/tick µs")
    rows: list[list[Any]] = [[side, *(res[side][k] for k in keys)] for side in ("floor", "loop")]
    rows.append(["added", *(res["added"].get(k, "") for k in keys)])
    print(f"period {res['period_us']:.0f} µs, {res['seconds']:g} s each (lateness = wake − deadline)")
    print_table(rows, heads)
    print()
    print_table(
        [[d, f, lp] for d, f, lp in zip(_DECADES, res["floor_decades"], res["loop_decades"], strict=True)],
        ("lateness", "floor ticks", "loop ticks"),
    )
    rt = res["realtime"]
    print()
    if isinstance(rt, dict):
        for k, v in rt.items():
            print(f"{k}: {v}")
    else:
        print(f"realtime: {rt}")
    print(f"SIL plant at the end: {res['sil_rps']:.2f} rev/s")
    run, latch = res["loop"]["longest_late_run"], res["overrun_latch_ticks"]
    verdict = "would have latched" if res["would_latch"] else "below"
    print(f"longest run of late ticks: {run} ({verdict} the daemon's overrun latch, {latch} ticks)")
