"""`tvsctl bench --only doctor`: what its figures measure, and a parallel matrix that answers as
the serial one does (every case seeded, BLAS on one thread in each)."""

from __future__ import annotations

import sys

import pytest

from tvsd.analysis import bench


def test_child_figures_are_that_childs_own():
    """wait4's rusage is the child's alone: a small child after a 300 MiB one reports its own
    peak (RUSAGE_CHILDREN would keep the largest child so far), and CPU spent in a busy loop
    shows up as CPU (≥ 0.2 s of a 0.3 s spin: the child gets ≥ 2/3 of a core even when shared)."""
    big = [sys.executable, "-c", "b = bytearray(300 * 2**20); b[::4096] = b'x' * len(b[::4096])"]
    _, _, peak_big = bench._child(big, {})
    spin = [
        sys.executable,
        "-c",
        "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass",
    ]
    _, cpu, peak_small = bench._child(spin, {})
    assert peak_big > 300
    assert peak_small < 100
    assert cpu >= 0.25


def test_child_failure_names_the_exit():
    with pytest.raises(RuntimeError, match="exited 3"):
        bench._child([sys.executable, "-c", "import sys; sys.exit(3)"], {})


def test_spread_keeps_nulls_and_causes():
    items = list(range(158))
    assert bench.spread(items, None) == items and bench.spread(items, 500) == items
    picked = bench.spread(items, 20)
    assert len(picked) == 20 and picked[0] == 0 and picked[-1] >= 150
    assert len(set(picked)) == 20


@pytest.mark.slow
def test_parallel_matrix_answers_as_serial():
    """Two workers against one process on the same four cases (10 s recordings): the same
    answer for every case, so the same figures but for time."""
    serial = bench.run_matrix("open", cases=4, workers=1, seconds=10.0)
    parallel = bench.run_matrix("open", cases=4, workers=2, seconds=10.0)
    timing = ("_wall_s", "_cpu_s", "_mean_analyze_s", "_workers")
    strip = lambda f: {k: v for k, v in f.items() if not k.endswith(timing)}  # noqa: E731
    assert parallel["doctor_open_workers"] == 2 and serial["doctor_open_workers"] == 1
    assert strip(parallel) == strip(serial)
    assert serial["doctor_open_cases"] == 4


@pytest.mark.slow
def test_doctor_long_reports_time_memory_and_the_estimate(capsys):
    """`tvsctl bench --only doctor_long`: per size the wall, CPU and the child's own peak RSS of
    `tvsctl analyze`, beside the doctor's estimate (tvsd.analysis.memory), which must not
    undershoot the measured peak by more than the interpreter's scatter (±10 %)."""
    import json

    from tvsd.cli.main import main

    assert main(["bench", "--only", "doctor_long", "--doctor-sizes", "20@1000,10@2000", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    for key in ("doctor_long_20s_1khz", "doctor_long_10s_2khz"):
        assert got[f"{key}_wall_s"] > 0 and got[f"{key}_cpu_s"] > 0, got
        assert got[f"{key}_peak_rss_mib"] <= 1.1 * got[f"{key}_estimate_mib"], got


def test_doctor_sizes_are_checked():
    from tvsd.cli.bench import _sizes

    assert _sizes("60@1000,3600@2000") == ((60.0, 1000.0), (3600.0, 2000.0))
    for bad in ("60", "60@3000", "0@1000", "x@y"):
        with pytest.raises(Exception, match="seconds@Hz"):
            _sizes(bad)
