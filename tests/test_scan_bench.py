"""The scan benchmarks run and measure what they say (figures themselves go to README)."""

from __future__ import annotations

import math

from tvsd.sim.scan_bench import bench_latency, bench_triangulation


def test_triangulation_bench_reports_a_rate():
    res = bench_triangulation(n=20_000, repeats=1)
    assert res["scan_triangulation_points_per_s"] > 1e5  # vectorised numpy: millions/s here


def test_latency_bench_separates_the_methods_wait():
    res = bench_latency(seconds=1.5, rps=20.0)
    # Causal: out at the first IMU sample after the optical pulse (≤ 1 ms). Centred: waits for the
    # next zero pulse, (2π − β)/ω ≈ 35 ms at 20 rev/s for β = 106°, plus that sample.
    assert res["scan_latency_causal_wait_ms"] <= 1.0
    assert 30.0 < res["scan_latency_centred_wait_ms"] < 50.0
    assert all(math.isfinite(v) and v > 0 for v in res.values())


def test_pipeline_bench_counts_points():
    from tvsd.sim.scan_bench import bench_pipeline

    res = bench_pipeline(seconds=2.0, repeats=1)
    assert res["scan_pipeline_points_per_s"] > 1e3  # ~1e4 here; 25 rev/s needs 25
