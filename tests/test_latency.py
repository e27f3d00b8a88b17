"""The floor loop, the histogram statistics and `tvsctl latency` (function, never timing)."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from tvsd.cli import latency as cli
from tvsd.control import latency as L


def test_edges_are_log_spaced_to_10_ms() -> None:
    assert L.EDGES_NS[0] == 0 and L.EDGES_NS[1] == 1_000 and L.EDGES_NS[-1] == 10_000_000
    ratios = L.EDGES_NS[2:] / L.EDGES_NS[1:-1]
    assert np.allclose(ratios, 10 ** (1 / L.BINS_PER_DECADE), rtol=2e-3)


@pytest.mark.parametrize("late_ns", [0, 999, 1_000, 1_500, 73_000, 9_999_999, 10_000_000, 10**12])
def test_bin_contains_the_lateness(late_ns: int) -> None:
    b = L._bin.py_func(late_ns, L.EDGES_NS)
    assert L.EDGES_NS[b] <= late_ns
    assert b == len(L.EDGES_NS) - 1 or late_ns < L.EDGES_NS[b + 1]


def test_quantiles_from_a_known_histogram() -> None:
    hist = np.zeros(L.N_BINS, dtype=np.int64)
    b50 = L._bin.py_func(50_000, L.EDGES_NS)
    b2000 = L._bin.py_func(2_000_000, L.EDGES_NS)
    hist[b50], hist[b2000] = 990, 10
    assert L.quantile_us(hist, 0.5) == pytest.approx(50.0, rel=0.05)
    assert L.quantile_us(hist, 0.99) == pytest.approx(50.0, rel=0.05)
    assert L.quantile_us(hist, 0.999) == pytest.approx(2000.0, rel=0.05)
    assert math.isnan(L.quantile_us(np.zeros(L.N_BINS, dtype=np.int64), 0.5))


def test_floor_runs_its_ticks_and_counts_them() -> None:
    ints, hist = L.run_floor(0.05, 1e-4)
    assert ints[L.K_TICKS] == 500 == int(hist.sum())
    assert ints[L.K_RUNNING] == 0
    j = L.jitter(ints, hist)
    # Ticks and skipped deadlines account for the whole elapsed time: the first deadline is one
    # period after start, and the last wake is less than one period past the deadline it served.
    elapsed_periods = (ints[L.K_LAST_NS] - ints[L.K_START_NS]) / ints[L.K_PERIOD_NS]
    assert j.ticks + j.missed_ticks <= elapsed_periods < j.ticks + j.missed_ticks + 1
    both = L.merge((ints, hist), (ints.copy(), hist.copy()))
    assert both.ticks == 1000 and both.max_us == j.max_us
    assert both.rate_hz == pytest.approx(j.rate_hz, rel=1e-9)


def test_decades_partition_the_histogram() -> None:
    hist = np.arange(L.N_BINS, dtype=np.int64)
    assert sum(L.decades(hist)) == int(hist.sum())


def test_cli_json_reports_floor_and_loop(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers())
    args = parser.parse_args(["latency", "--seconds", "0.4", "--json", "--no-realtime"])
    assert args.func(args) == 0
    res = json.loads(capsys.readouterr().out)
    for side in ("floor", "loop"):
        assert res[side]["ticks"] == 4000  # floor: two halves of 2000
        assert sum(c for _, c in res[f"{side}_histogram"]) == res[side]["ticks"]
        assert set(res[side]) >= {"p50_us", "p99_us", "p999_us", "max_us", "missed_ticks", "rate_hz"}
    assert res["added"]["p50_us"] == pytest.approx(res["loop"]["p50_us"] - res["floor"]["p50_us"])
    assert res["realtime"] == "not requested"
    # The overrun latch is off while measuring, so the law runs throughout however loaded the machine:
    # 0.4 s of a 10 rev/s² ramp (the plant follows the wall clock) has the plant above 0.5 rev/s.
    assert res["sil_rps"] > 0.5
    assert res["overrun_latch_ticks"] == 1000  # 100 ms at 10 kHz, the daemon's default
    assert res["would_latch"] == (res["loop"]["longest_late_run"] >= 1000)


def test_cli_table_and_bad_seconds(capsys: pytest.CaptureFixture[str]) -> None:
    parser = argparse.ArgumentParser()
    cli.register(parser.add_subparsers())
    args = parser.parse_args(["latency", "--seconds", "0.1", "--no-realtime"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "floor" in out and "loop" in out and "added" in out and "p99.9 µs" in out
    bad = parser.parse_args(["latency", "--seconds", "0"])
    with pytest.raises(cli.UsageError, match="--seconds"):
        bad.func(bad)


def test_wait_tick_accounting() -> None:
    """A deadline 5.5 periods in the past: one late tick, 5 deadlines skipped, phase kept."""
    ints, hist = L.new_timing(1.0)
    ts = np.zeros(2, dtype=np.int64)
    now = L.now_ns(ts)
    wake, served = L.wait_tick(ints, hist, L.EDGES_NS, ts, now - 5_500_000_000)
    assert ints[L.K_MISSED] == 5 and ints[L.K_LATE_TICKS] == 1 and ints[L.K_STREAK] == 1
    assert served == now - 500_000_000
    assert hist[-1] == 1  # ≥ 10 ms: overflow bin
    wake, served = L.wait_tick(ints, hist, L.EDGES_NS, ts, L.now_ns(ts) + 1_000_000)
    assert ints[L.K_STREAK] == 0 and ints[L.K_MISSED] == 5
    assert wake >= served
    assert int(hist.sum()) == 2
