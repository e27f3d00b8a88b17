"""`tvsctl bench`: the benchmark suite (figures for README's Benchmarks section)."""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from collections.abc import Callable
from typing import Any

from tvsd.cli.argtypes import count
from tvsd.cli.output import print_json, print_pairs
from tvsd.errors import EXIT_FAILURE, EXIT_OK

EXIT_INTERRUPTED = 130  # as tvsctl's other commands on Ctrl-C (128 + SIGINT)


def _sim() -> dict[str, Any]:
    from tvsd.sim import bench

    out = bench.sim_realtime_factor()
    out["control_step_ns"] = bench.control_step_ns()
    out["cli_warm_start_s"] = bench.cli_warm_start_s()
    return out


def _scan() -> dict[str, Any]:
    from tvsd.sim import scan_bench as bench

    return {
        **bench.bench_triangulation(),
        **bench.bench_pipeline(),
        **bench.bench_latency(),
        **bench.bench_stream(),
    }


def _imu() -> dict[str, Any]:
    from tvsd.cli.imu import bench_capture

    return {f"imu_{k}": v for k, v in bench_capture(5.0).items()}


def _imu_sil() -> dict[str, Any]:
    from tvsd.sim.i2c_bench import bench_sil_bus

    return bench_sil_bus()


def _mcu() -> dict[str, Any]:
    from tvsd.hw.mcu.framing import bench_decode

    return {f"mcu_decode_{k}": v for k, v in bench_decode().items()}


def _loop() -> dict[str, Any]:
    from tvsd.control.latency import bench_loop

    return bench_loop()


def _mcu_io() -> dict[str, Any]:
    from tvsd.control.link_bench import bench_kernel_heartbeat
    from tvsd.hw.mcu.io_bench import bench_io_thread

    return {**bench_io_thread(), **bench_kernel_heartbeat()}  # the I/O thread's, then the kernel's


def _mcu_sil() -> dict[str, Any]:
    from tvsd.sim.clock_sync_bench import bench_clock_sync

    return bench_clock_sync()


def _mcu_stm32() -> dict[str, Any]:
    from tvsd.sim.stm32_bench import bench_stm32

    return bench_stm32()


def _fuzz(frames: int = 1_000_000) -> dict[str, Any]:
    from tvsd.hw.mcu.fuzz_bench import bench_fuzz

    return bench_fuzz(frames)


def _doctor(args: argparse.Namespace) -> dict[str, Any]:
    from tvsd.analysis.bench import bench_doctor
    from tvsd.cli.progress import on_terminal

    def say(message: str) -> None:
        if on_terminal():
            print(f"  doctor: {message}", file=sys.stderr, flush=True)

    return bench_doctor(
        cases=args.cases,
        workers=args.workers,
        progress=say,
        n_null=args.nulls,
        reps=args.reps,
        seed=args.matrix_seed,
    )


def _doctor_long(args: argparse.Namespace) -> dict[str, Any]:
    from tvsd.analysis.bench import LONG_SIZES, bench_long
    from tvsd.cli.progress import on_terminal

    def say(message: str) -> None:
        if on_terminal():
            print(f"  doctor_long: {message}", file=sys.stderr, flush=True)

    return bench_long(args.doctor_sizes or LONG_SIZES, progress=say)


def _api() -> dict[str, Any]:
    from tvsd.daemon.bench import bench_point_latency

    return bench_point_latency()


def _soak(args: argparse.Namespace) -> dict[str, Any]:
    from tvsd.cli.progress import progress_bar
    from tvsd.daemon.soak import soak

    with progress_bar(f"soak {args.seconds:g} s", args.seconds) as advance:
        # --clients 0: the CPU hogs alone (no batches either), the test_soak "alone" load
        return soak(args.seconds, clients=args.clients, batches=args.clients > 0, progress=advance)


# name -> function returning a flat dict of figures; one line per benchmark group.
BENCHES: dict[str, Callable[..., dict[str, Any]]] = {
    "sim": _sim,
    "scan": _scan,
    "imu": _imu,
    "imu_sil": _imu_sil,
    "mcu": _mcu,
    "mcu_io": _mcu_io,
    "mcu_sil": _mcu_sil,
    "mcu_stm32": _mcu_stm32,
    "fuzz": _fuzz,
    "doctor": _doctor,
    "loop": _loop,
    "api": _api,
}
# Groups run only when named (--only): soak takes 10 min and loads every core.
# doctor_long: tvsctl analyze's wall time and peak memory by recording length (1 h: minutes each).
ON_REQUEST: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    "soak": _soak,
    "doctor_long": _doctor_long,
}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "bench",
        help="run the benchmarks and print the figures",
        description="Runs each group and prints its figures as soon as it finishes; Ctrl-C keeps "
        "(and prints) the groups done so far. Groups take 0.3 s to 2 min each on 2 cores; soak, "
        "run only when named, takes --seconds (10 min) and loads every core. Exit status 1 when "
        "the soak misses a target.",
    )
    p.add_argument(
        "--only", choices=sorted([*BENCHES, *ON_REQUEST]), action="append", help="run only these groups"
    )
    p.add_argument("--json", action="store_true", help="print one JSON object (at the end, or on Ctrl-C)")
    p.add_argument(
        "--frames",
        type=_positive_int,
        default=1_000_000,
        help="damaged frames per decoder for the fuzz group (default 10^6: 7 s idle, ~70 s loaded)",
    )
    p.add_argument(
        "--nulls",
        type=count(0, 100_000, "a number of null recordings"),
        default=50,
        metavar="N",
        help="doctor: null recordings per loop (default 50; ≈ 2 s of CPU each)",
    )
    p.add_argument(
        "--reps",
        type=count(0, 1000, "a number of effect cases"),
        default=3,
        metavar="N",
        help="doctor: effect cases per cause and size (default 3; 0: the nulls alone)",
    )
    p.add_argument(
        "--matrix-seed",
        type=count(0, 2**31, "a seed"),
        default=0,
        metavar="S",
        help="doctor: the matrix's seed, both loops (default 0)",
    )
    p.add_argument(
        "--seconds", type=_positive_float, default=600.0, metavar="S", help="soak: its length (default 600)"
    )
    p.add_argument(
        "--cases",
        type=_cases,
        metavar="N",
        help="doctor: N matrix cases per loop, spread over nulls, causes and sizes (default: all; 158 "
        "at the default --nulls and --reps; "
        "20 take ~5 min on 2 cores)",
    )
    p.add_argument(
        "--workers",
        type=_workers,
        metavar="N",
        help="doctor: processes the matrix's cases run in (default: one per core; answers as serial)",
    )
    p.add_argument(
        "--clients",
        type=_clients,
        default=50,
        metavar="N",
        help="soak: RPC clients polling status (default 50; 0: the CPU hogs alone, no batches)",
    )
    p.add_argument(
        "--doctor-sizes",
        type=_sizes,
        metavar="S@HZ,...",
        help="doctor_long: recordings to time, seconds@Hz (default 60@1000,120@2000; 1 h: 3600@1000)",
    )
    p.set_defaults(func=_run)


def _sizes(text: str) -> tuple[tuple[float, float], ...]:
    """`60@1000,3600@2000` → ((60, 1000), (3600, 2000)); the rate must divide the 10 kHz loop."""
    out = []
    for part in text.split(","):
        try:
            s, hz = (float(x) for x in part.split("@"))
        except ValueError:
            s, hz = 0.0, 0.0
        if not (1.0 <= s <= 86_400 and hz > 0 and (10_000 / hz).is_integer()):
            raise argparse.ArgumentTypeError(
                f"expected seconds@Hz (1 s to 24 h, a rate dividing 10 kHz), got {part!r}"
            )
        out.append((s, hz))
    return tuple(out)


def _words(value: Any) -> Any:
    """A dict figure (faults by kind, answers by code) as `a=1, b=2` in the table; `none` if empty."""
    if isinstance(value, dict):
        return ", ".join(f"{k}={v}" for k, v in value.items()) or "none"
    return value


_positive_int = count(1, 10**9, "a whole number of frames")
_clients = count(0, 1000, "a number of clients")
_cases = count(1, 100_000, "a number of matrix cases")
_workers = count(1, 256, "a number of worker processes")


def _positive_float(text: str) -> float:
    try:
        x = float(text)
    except ValueError:
        x = 0.0
    if not 0 < x < 1e6:
        raise argparse.ArgumentTypeError(f"expected seconds > 0 (and below 10^6), got {text!r}")
    return x


def _run(args: argparse.Namespace) -> int:
    from tvsd.cli.progress import on_terminal

    figures: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    }
    groups = list(dict.fromkeys(args.only or BENCHES))
    if not args.json:
        print_pairs(figures)
    done: list[str] = []
    try:
        for n, name in enumerate(groups, 1):
            if on_terminal():
                print(f"[{n}/{len(groups)}] {name} …", file=sys.stderr, flush=True)
            t0 = time.monotonic()
            if name in ON_REQUEST:
                got = ON_REQUEST[name](args)
            elif name == "fuzz":
                got = BENCHES[name](args.frames)
            elif name == "doctor":
                got = BENCHES[name](args)
            else:
                got = BENCHES[name]()
            figures.update(got)
            done.append(name)
            if not args.json:  # each group as it finishes: a long suite is never silent
                print(f"\n# {name} ({time.monotonic() - t0:.1f} s)")
                print_pairs({k: _words(v) for k, v in got.items()})
                sys.stdout.flush()
    except KeyboardInterrupt:
        left = groups[len(done) :]
        rest = f"; not run: {', '.join(left[1:])}" if left[1:] else ""
        kept = ", ".join(done) or "no group"
        print(f"tvsctl: bench interrupted in {left[0]}, kept {kept}{rest}", file=sys.stderr)
        if args.json:
            print_json({**figures, "groups_done": done, "interrupted_in": left[0]})
        return EXIT_INTERRUPTED
    if args.json:
        print_json({**figures, "groups_done": done})
    return EXIT_FAILURE if figures.get("soak_pass") is False else EXIT_OK
