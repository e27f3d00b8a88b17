"""tvsctl mcu — talk to the MCU directly: who it is, how fast it answers, what it counted.

  tvsctl mcu identify [--port PATH | --sil] [--baud N] [--json]
  tvsctl mcu ping     [--port PATH | --sil] [--baud N] [--count N] [--interval S] [--timeout S] [--json]
  tvsctl mcu stats    [--port PATH | --sil] [--baud N] [--seconds S] [--json]

--sil runs the firmware core on the host behind a pseudo-terminal (tvsd.sim.virtual_mcu), so the
same commands check the protocol end to end without a board.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import statistics
from collections.abc import AsyncIterator, Callable, Coroutine, Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

from tvsd.cli import argtypes
from tvsd.cli.output import print_json, print_pairs, print_table
from tvsd.errors import EXIT_FAILURE, EXIT_OK, DeviceError, UsageError
from tvsd.hw.mcu.link import McuLink
from tvsd.hw.mcu.settings import McuSettings
from tvsd.hw.mcu.spec import load_spec

DEFAULT_BAUD = 2_000_000


@contextlib.contextmanager
def _port(args: argparse.Namespace) -> Iterator[str]:
    """The serial port to open: --port as given, or a virtual MCU's pty for --sil."""
    if not args.sil:
        yield args.port
        return
    try:
        from tvsd.sim.virtual_mcu import VirtualMcu
    except ImportError as exc:
        raise DeviceError(
            f"--sil needs the virtual MCU (tvsd.sim.virtual_mcu), which cannot be loaded "
            f"({exc}); use --port with a real MCU"
        ) from exc
    with VirtualMcu() as vmcu:
        yield vmcu.port


@contextlib.asynccontextmanager
async def _link(args: argparse.Namespace, port: str, heartbeat: bool) -> AsyncIterator[McuLink]:
    link = McuLink(McuSettings(port=port, baud=args.baud))
    await link.open()
    try:
        await link.identify()
        if heartbeat:
            link.start_heartbeat()
        yield link
    finally:
        await link.close()


def _run(args: argparse.Namespace, body: Callable[[str], Coroutine[Any, Any, int]]) -> int:
    if args.baud <= 0:  # checked before a virtual MCU is started for nothing
        raise UsageError(f"--baud must be a positive number of bits per second, got {args.baud}")
    with _port(args) as port:
        return asyncio.run(body(port))


def cmd_identify(args: argparse.Namespace) -> int:
    async def body(port: str) -> int:
        spec = load_spec()
        link = McuLink(McuSettings(port=port, baud=args.baud), spec)
        await link.open()
        try:
            # identify() refuses a mismatch with the fix in the message; report it the same way
            ident = await link.identify()
        finally:
            await link.close()
        out = {
            "port": "sil" if args.sil else port,
            "proto_version": ident.proto_version,
            "table_hash": f"0x{ident.table_hash:08X}",
            "clock_hz": ident.clock_hz,
            "board": spec.boards.get(ident.board, f"unknown ({ident.board})"),
            "host_proto_version": spec.version,
            "host_table_hash": f"0x{spec.table_hash:08X}",
            "match": True,
        }
        if args.json:
            print_json(out)
        else:
            print_pairs(out)
        return EXIT_OK

    return _run(args, body)


def _ping_plot(rtt_us: list[float], marks: dict[str, float], where: str, path: Path) -> None:
    """Histogram of the round trips (log-spaced bins: the tail is what matters), p50/p99 marked."""
    import numpy as np

    from tvsd.sim.plots import figure, save_png

    plt, fig, ax = figure(1, 1, (8, 4))
    lo, hi = max(min(rtt_us), 1.0), max(max(rtt_us), 2.0)
    ax.hist(rtt_us, bins=np.geomspace(lo, hi * 1.01, 40))
    ax.set_xscale("log")
    for name, style in (("p50", "--"), ("p99", ":")):
        ax.axvline(marks[name], color="r", lw=0.9, ls=style, label=f"{name} {marks[name]:.0f} µs")
    ax.set(
        xlabel="round trip (µs)",
        ylabel="heartbeats",
        title=f"MCU heartbeat round trips: {len(rtt_us)} ({where})",
    )
    ax.legend()
    save_png(plt, fig, path)


def _percentile(sorted_values: list[float], q: float) -> float:
    i = min(len(sorted_values) - 1, max(0, round(q * (len(sorted_values) - 1))))
    return sorted_values[i]


def cmd_ping(args: argparse.Namespace) -> int:
    if args.count <= 0:
        raise UsageError(f"--count must be at least 1, got {args.count}")
    if args.interval < 0:
        raise UsageError(f"--interval must not be negative, got {args.interval}")
    if not 0 < args.timeout <= 60:  # NaN too
        raise UsageError(f"--timeout must be more than 0 s, got {args.timeout} (and at most 60 s)")
    if args.plot is not None and args.plot.suffix.lower() != ".png":
        raise UsageError(f"--plot {args.plot}: the plot is written as PNG; give a file name ending in .png")

    async def body(port: str) -> int:
        rtts: list[float] = []
        lost = 0
        async with _link(args, port, heartbeat=False) as link:
            for _ in range(args.count):
                try:
                    rtts.append(await link.ping(timeout_s=args.timeout))
                except DeviceError:
                    lost += 1
                await asyncio.sleep(args.interval)
        if not rtts:
            raise DeviceError(f"the MCU on {port} answered none of {args.count} heartbeats")
        s = sorted(rtts)
        rtt_us = {
            "min": s[0] * 1e6,
            "p50": statistics.median(s) * 1e6,
            "p90": _percentile(s, 0.9) * 1e6,
            "p99": _percentile(s, 0.99) * 1e6,
            "max": s[-1] * 1e6,
        }
        if args.plot:
            _ping_plot(
                [r * 1e6 for r in rtts], rtt_us, f"{'sil' if args.sil else port}, {lost} lost", args.plot
            )
        if args.json:
            print_json({"count": args.count, "answered": len(rtts), "lost": lost, "rtt_us": rtt_us})
        else:
            print(f"{len(rtts)} of {args.count} heartbeats answered, round trip in µs:")
            print_table([[round(v, 1) for v in rtt_us.values()]], headers=list(rtt_us))
        return EXIT_OK if lost == 0 else EXIT_FAILURE

    return _run(args, body)


def cmd_stats(args: argparse.Namespace) -> int:
    if args.seconds < 0:
        raise UsageError(f"--seconds must not be negative, got {args.seconds}")

    async def body(port: str) -> int:
        async with _link(args, port, heartbeat=True) as link:
            await asyncio.sleep(args.seconds)
            mcu = await link.request_stats()
            host = link.stats().as_dict()
        out: dict[str, Any] = {"host": host, "mcu": asdict(mcu)}
        if args.json:
            print_json(out)
        else:
            rows = [("host", k, v) for k, v in host.items()]
            rows += [("mcu", k, v) for k, v in out["mcu"].items()]
            print_table(rows, headers=["side", "counter", "value"])
        return EXIT_OK

    return _run(args, body)


def _common(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--port", metavar="PATH", help="serial device of the MCU, e.g. /dev/ttyUSB0")
    src.add_argument("--sil", action="store_true", help="use the virtual MCU (firmware on a pty)")
    p.add_argument("--baud", type=int, default=DEFAULT_BAUD, help="default %(default)s")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def register(subparsers: argparse._SubParsersAction) -> None:
    mcu = subparsers.add_parser("mcu", help="MCU link: identify, ping, stats")
    sub = mcu.add_subparsers(dest="mcu_command", metavar="SUBCOMMAND", parser_class=type(mcu))
    sub.required = True
    ident = sub.add_parser("identify", help="protocol version, command-table hash, clock, board")
    _common(ident)
    ident.set_defaults(func=cmd_identify)
    ping = sub.add_parser("ping", help="heartbeat round-trip times")
    _common(ping)
    ping.add_argument("--count", type=int, default=100, help="heartbeats (default %(default)s)")
    ping.add_argument(
        "--interval",
        type=argtypes.number(0, 60, "s"),
        default=0.01,
        help="s between (%(default)s)",
    )
    ping.add_argument(
        "--timeout",
        type=float,
        default=0.2,
        help="s to wait for each answer (%(default)s)",
    )
    ping.add_argument(
        "--plot", type=Path, metavar="FILE.png", help="draw the round-trip histogram into FILE.png"
    )
    ping.set_defaults(func=cmd_ping)
    stats = sub.add_parser("stats", help="link counters of both sides")
    _common(stats)
    stats.add_argument(
        "--seconds",
        type=argtypes.number(0, 3600, "s"),
        default=1.0,
        help="listen first (%(default)s)",
    )
    stats.set_defaults(func=cmd_stats)
