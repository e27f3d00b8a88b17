"""`tvsctl bench`: the benchmark suite (figures for README's Performance section)."""

from __future__ import annotations

import argparse
import os
import platform
from collections.abc import Callable
from typing import Any

from tvsd.cli.output import print_json, print_pairs
from tvsd.errors import EXIT_OK


def _sim() -> dict[str, Any]:
    from tvsd.sim import bench

    out = bench.sim_realtime_factor()
    out["control_step_ns"] = bench.control_step_ns()
    out["cli_warm_start_s"] = bench.cli_warm_start_s()
    return out


def _scan() -> dict[str, Any]:
    from tvsd.sim import scan_bench as bench

    return {**bench.bench_triangulation(), **bench.bench_pipeline(), **bench.bench_latency()}


def _imu() -> dict[str, Any]:
    from tvsd.cli.imu import bench_capture

    return {f"imu_{k}": v for k, v in bench_capture(5.0).items()}


def _mcu() -> dict[str, Any]:
    from tvsd.hw.mcu.framing import bench_decode

    return {f"mcu_decode_{k}": v for k, v in bench_decode().items()}


def _loop() -> dict[str, Any]:
    from tvsd.control.latency import bench_loop

    return bench_loop()


def _mcu_sil() -> dict[str, Any]:
    from tvsd.sim.mcu_plant import bench_clock_sync

    return bench_clock_sync()


def _doctor() -> dict[str, Any]:
    from tvsd.analysis.bench import bench_doctor

    return bench_doctor()


def _api() -> dict[str, Any]:
    from tvsd.daemon.bench import bench_point_latency

    return bench_point_latency()


# name -> function returning a flat dict of figures; one line per benchmark group.
BENCHES: dict[str, Callable[[], dict[str, Any]]] = {
    "sim": _sim,
    "scan": _scan,
    "imu": _imu,
    "mcu": _mcu,
    "mcu_sil": _mcu_sil,
    "doctor": _doctor,
    "loop": _loop,
    "api": _api,
}


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("bench", help="run the benchmarks and print the figures")
    p.add_argument("--only", choices=sorted(BENCHES), action="append", help="run only these groups")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    figures: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    }
    for name in args.only or BENCHES:
        figures.update(BENCHES[name]())
    if args.json:
        print_json(figures)
    else:
        print_pairs(figures)
    return EXIT_OK
