"""Benchmark of the model doctor: a 60 s, 1 kHz recording analysed in one process."""

from __future__ import annotations

import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def bench_doctor(n_null: int = 50, reps: int = 3, seed: int = 0) -> dict[str, object]:
    """The 60 s timing, then the randomised matrix (tvsd.analysis.matrix: `n_null` nulls and
    `reps` effect cases per cause and size), open loop and closed loop (scanning with tvsctl
    identify's excitation)."""
    from tvsd.analysis.matrix import run

    return {
        **bench_analyze(),
        **run(n_null=n_null, reps=reps, seed=seed, loop="open"),
        **run(n_null=n_null, reps=reps, seed=seed, loop="closed"),
    }


def bench_analyze(seconds: float = 60.0) -> dict[str, float]:
    """Wall time and peak memory of `tvsctl analyze` on a SIL staircase with a hidden dead zone.

    Runs in a child process so its peak resident memory is its own (getrusage of the children).
    """
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "bench.csv"
        cli = [sys.executable, "-m", "tvsd.cli.main"]
        subprocess.run(
            [
                *cli,
                "sim",
                "record",
                "--out",
                str(rec),
                "--seconds",
                f"{seconds:g}",
                "--effect",
                "deadzone:u0=0.8",
                "--seed",
                "7",
            ],
            check=True,
            capture_output=True,
        )
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        t0 = time.perf_counter()
        subprocess.run([*cli, "analyze", str(rec), "--json", "--quiet"], check=True, capture_output=True)
        wall = time.perf_counter() - t0
        peak_kib = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return {
        "analyze_60s_recording_s": wall,
        "analyze_peak_rss_mib": max(peak_kib, before) / 1024.0,
        "analyze_recording_s": seconds,
    }
