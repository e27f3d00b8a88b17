"""Wake-up timing on absolute deadlines: the clock primitives, the jitter histogram, the floor.

The control runner (tvsd.control.runner) and the floor loop here share `wait_tick`, so both
measure lateness the same way: CLOCK_MONOTONIC, `clock_nanosleep(TIMER_ABSTIME)`, lateness =
wake time − deadline, binned in a log-spaced µs histogram. The floor is a bare sleep loop (as
`cyclictest`): what this machine adds by itself. The control loop's goal is to add nothing to it.

The libc calls are numba `ExternalFunction`s (symbols resolved when the kernel is linked), so the
kernels stay nopython, nogil and cacheable: no ctypes pointers, no C extension.
"""

from __future__ import annotations

import math
import threading
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numba import njit, types

CLOCK_MONOTONIC = 1
CLOCK_THREAD_CPUTIME_ID = 3
TIMER_ABSTIME = 1
EINTR = 4
NS = 1_000_000_000

# Typed Any: numba types are not callables to mypy, they are to the nopython compiler.
_clock_gettime: Any = types.ExternalFunction("clock_gettime", types.int32(types.int32, types.voidptr))
_clock_nanosleep: Any = types.ExternalFunction(
    "clock_nanosleep", types.int32(types.int32, types.int32, types.voidptr, types.voidptr)
)

# Shared int64 words of a timed loop (the runner appends its own after N_TIMING).
(
    K_STOP,  # I/O side sets 1: the loop returns after the current tick
    K_PERIOD_NS,
    K_MAX_TICKS,  # > 0: stop after this many ticks (tests, fixed-length measurements)
    K_TICKS,
    K_MISSED,  # deadlines skipped: a tick that wakes more than one period late skips them
    K_LATE_TICKS,  # ticks that woke more than one period late
    K_STREAK,  # current run of consecutive late ticks
    K_LONGEST_STREAK,  # longest such run so far (what an overrun latch at that length would see)
    K_MAX_LATE_NS,
    K_START_NS,
    K_LAST_NS,  # wake time of the last tick (CLOCK_MONOTONIC)
    K_CPU_NS,  # thread CPU time spent inside the kernel
    K_WORK_NS,  # sum over ticks of wake → work done (monotonic)
    K_WORK_MAX_NS,
    K_RUNNING,
) = range(15)
N_TIMING = 15

# Histogram: bin 0 = [0, 1 µs), then 25 log-spaced bins per decade to 10 ms, last bin ≥ 10 ms.
BINS_PER_DECADE = 25
EDGES_NS = np.concatenate(
    ([0], np.round(1000.0 * 10.0 ** (np.arange(4 * BINS_PER_DECADE + 1) / BINS_PER_DECADE)))
).astype(np.int64)
N_BINS = len(EDGES_NS)


@njit(cache=True, nogil=True, inline="always")
def now_ns(ts: np.ndarray) -> int:
    """CLOCK_MONOTONIC in ns; `ts` is an int64[2] timespec scratch (tv_sec, tv_nsec)."""
    _clock_gettime(CLOCK_MONOTONIC, ts.ctypes)
    return ts[0] * NS + ts[1]


@njit(cache=True, nogil=True, inline="always")
def thread_cpu_ns(ts: np.ndarray) -> int:
    _clock_gettime(CLOCK_THREAD_CPUTIME_ID, ts.ctypes)
    return ts[0] * NS + ts[1]


@njit(cache=True, nogil=True, inline="always")
def _bin(late: int, edges: np.ndarray) -> int:
    """Bisection: index i with edges[i] ≤ late < edges[i+1] (no allocation, unlike searchsorted)."""
    if late < edges[1]:
        return 0
    lo, hi = 1, edges.shape[0] - 1
    if late >= edges[hi]:
        return hi
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if late >= edges[mid]:
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def wait_tick(
    ints: np.ndarray, hist: np.ndarray, edges: np.ndarray, ts: np.ndarray, deadline: int
) -> tuple[int, int]:
    """Sleep until `deadline`, account the lateness; return (wake time, deadline served).

    A wake more than one period late skips the deadlines it missed (phase kept), so one long
    stall costs one late tick and counts its missed deadlines, not a burst of catch-up ticks.
    """
    while True:
        ts[0] = deadline // NS
        ts[1] = deadline % NS
        # TIMER_ABSTIME never writes `remain`; EINTR (a signal) sleeps again to the same deadline.
        if _clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, ts.ctypes, ts.ctypes) != EINTR:
            break
    wake = now_ns(ts)
    late = max(wake - deadline, 0)
    hist[_bin(late, edges)] += 1
    if late > ints[K_MAX_LATE_NS]:
        ints[K_MAX_LATE_NS] = late
    period = ints[K_PERIOD_NS]
    if late > period:
        skipped = late // period
        ints[K_MISSED] += skipped
        ints[K_LATE_TICKS] += 1
        ints[K_STREAK] += 1
        if ints[K_STREAK] > ints[K_LONGEST_STREAK]:
            ints[K_LONGEST_STREAK] = ints[K_STREAK]
        deadline += skipped * period
    else:
        ints[K_STREAK] = 0
    ints[K_LAST_NS] = wake
    return wake, deadline


@njit(cache=True, nogil=True)
def floor_loop(ints: np.ndarray, hist: np.ndarray, edges: np.ndarray, ts: np.ndarray) -> None:
    """The machine's floor: the control loop's timing with no work in it."""
    ints[K_RUNNING] = 1
    cpu0 = thread_cpu_ns(ts)
    start = now_ns(ts)
    ints[K_START_NS] = start
    deadline = start + ints[K_PERIOD_NS]
    while ints[K_STOP] == 0:
        wake, deadline = wait_tick(ints, hist, edges, ts, deadline)
        ints[K_TICKS] += 1
        work = now_ns(ts) - wake
        ints[K_WORK_NS] += work
        if work > ints[K_WORK_MAX_NS]:
            ints[K_WORK_MAX_NS] = work
        if ints[K_MAX_TICKS] > 0 and ints[K_TICKS] >= ints[K_MAX_TICKS]:
            break
        deadline += ints[K_PERIOD_NS]
    ints[K_CPU_NS] += thread_cpu_ns(ts) - cpu0
    ints[K_RUNNING] = 0


def new_timing(period_s: float, max_ticks: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Fresh (ints, hist) for a timed loop; the runner allocates a longer `ints`."""
    ints = np.zeros(N_TIMING, dtype=np.int64)
    ints[K_PERIOD_NS] = round(period_s * NS)
    ints[K_MAX_TICKS] = max_ticks
    return ints, np.zeros(N_BINS, dtype=np.int64)


@dataclass(frozen=True)
class Jitter:
    """Lateness statistics of one timed loop (µs; percentiles from the histogram, ±5 %)."""

    ticks: int
    missed_ticks: int
    late_ticks: int
    longest_late_run: int
    rate_hz: float
    p50_us: float
    p99_us: float
    p999_us: float
    max_us: float
    work_mean_us: float
    work_max_us: float
    cpu_per_tick_us: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def quantile_us(hist: np.ndarray, q: float) -> float:
    """q-quantile of lateness, geometric middle of its bin (bin 0: 0.5 µs; overflow: its edge)."""
    total = int(hist.sum())
    if total == 0:
        return math.nan
    b = int(np.searchsorted(np.cumsum(hist), q * total, side="left"))
    if b == 0:
        return 0.5
    if b >= N_BINS - 1:
        return float(EDGES_NS[-1]) / 1e3
    return math.sqrt(float(EDGES_NS[b]) * float(EDGES_NS[b + 1])) / 1e3


def jitter(ints: np.ndarray, hist: np.ndarray) -> Jitter:
    """Statistics of a loop from its shared words (safe to call while it runs: a snapshot)."""
    ticks = int(ints[K_TICKS])
    end = int(ints[K_LAST_NS])
    elapsed = (end - int(ints[K_START_NS])) / NS if ticks > 1 else math.nan
    per = max(ticks, 1)
    return Jitter(
        ticks=ticks,
        missed_ticks=int(ints[K_MISSED]),
        late_ticks=int(ints[K_LATE_TICKS]),
        longest_late_run=int(ints[K_LONGEST_STREAK]),
        rate_hz=(ticks - 1) / elapsed if ticks > 1 and elapsed > 0 else math.nan,
        p50_us=quantile_us(hist, 0.5),
        p99_us=quantile_us(hist, 0.99),
        p999_us=quantile_us(hist, 0.999),
        max_us=int(ints[K_MAX_LATE_NS]) / 1e3,
        work_mean_us=int(ints[K_WORK_NS]) / per / 1e3,
        work_max_us=int(ints[K_WORK_MAX_NS]) / 1e3,
        cpu_per_tick_us=int(ints[K_CPU_NS]) / per / 1e3,
    )


def run_floor(seconds: float, period_s: float, setup_thread: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Run the floor loop for `seconds` in its own thread (after `setup_thread()` there)."""
    ints, hist = new_timing(period_s, max_ticks=max(1, round(seconds / period_s)))
    ts = np.zeros(2, dtype=np.int64)

    def body() -> None:
        if setup_thread is not None:
            setup_thread()
        floor_loop(ints, hist, EDGES_NS, ts)

    th = threading.Thread(target=body, name="tvsd-floor", daemon=True)
    th.start()
    th.join()
    return ints, hist


def merge(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> Jitter:
    """Statistics of two runs of the same loop (the floor before and after the control loop)."""
    ia, ha = a
    ib, hb = b
    ints = ia + ib
    ints[K_MAX_LATE_NS] = max(ia[K_MAX_LATE_NS], ib[K_MAX_LATE_NS])
    ints[K_WORK_MAX_NS] = max(ia[K_WORK_MAX_NS], ib[K_WORK_MAX_NS])
    ints[K_LONGEST_STREAK] = max(ia[K_LONGEST_STREAK], ib[K_LONGEST_STREAK])
    # Rate over the two runs' own durations (the gap between them is not the loop's).
    span = (ia[K_LAST_NS] - ia[K_START_NS]) + (ib[K_LAST_NS] - ib[K_START_NS])
    intervals = int(ia[K_TICKS] + ib[K_TICKS]) - 2
    rate = intervals / (span / NS) if span > 0 else math.nan
    return replace(jitter(ints, ha + hb), rate_hz=float(rate))


def warm_up() -> None:
    """Load or compile the kernels outside any measurement."""
    ints, hist = new_timing(1e-4, max_ticks=2)
    floor_loop(ints, hist, EDGES_NS, np.zeros(2, dtype=np.int64))


def histogram_rows(hist: np.ndarray) -> list[tuple[float, int]]:
    """Non-empty bins as (lower edge µs, count), for JSON."""
    return [(float(EDGES_NS[b]) / 1e3, int(c)) for b, c in enumerate(hist) if c]


def decades(hist: np.ndarray) -> list[int]:
    """Counts per decade: <1 µs, 1–10 µs, 10–100 µs, 0.1–1 ms, 1–10 ms, ≥ 10 ms."""
    out = [int(hist[0])]
    for d in range(4):
        out.append(int(hist[1 + d * BINS_PER_DECADE : 1 + (d + 1) * BINS_PER_DECADE].sum()))
    out.append(int(hist[-1]))
    return out


LATCH_OFF = 2**62  # a streak limit no run reaches


def compare(seconds: float, *, realtime: bool = True, rps: float = 25.0) -> dict[str, Any]:
    """Floor (half before, half after) and the SIL control loop, each `seconds` long, same thread setup.

    Returns {"floor": Jitter, "loop": Jitter, "added": loop − floor, "realtime": ..., histograms,
    "sil_rps", "overrun_latch_ticks" (the daemon's), "would_latch" (the loop's longest late run reached it)}.
    """
    # Imported here: the runner builds on this module's primitives.
    from tvsd.config import load_config
    from tvsd.control.runner import Runner, request_realtime
    from tvsd.control.setup import Setup

    cfg = load_config(params="default")
    # The overrun latch is off: on a busy machine it would stop the law mid-measurement (and the
    # plant with it); the longest run of late ticks is reported against the daemon's latch instead.
    latch = cfg.control.overrun_streak_ticks
    setup = Setup.from_config(cfg)
    runner = Runner(setup, realtime=realtime, streak_limit=LATCH_OFF)
    period = runner.period_s
    warm_up()
    runner.start(max_ticks=2)  # load the kernel outside the measurement
    runner.join(120.0)
    runner = Runner(setup, realtime=realtime, streak_limit=LATCH_OFF)
    setup_thread = request_realtime if realtime else None
    before = run_floor(seconds / 2, period, setup_thread)
    runner.scan(rps)
    runner.start(max_ticks=max(1, round(seconds / period)))
    runner.join(seconds * 10 + 10)
    after = run_floor(seconds / 2, period, setup_thread)
    floor, loop = merge(before, after), runner.stats()
    keys = ("p50_us", "p99_us", "p999_us", "max_us", "missed_ticks", "cpu_per_tick_us")
    fd, ld = floor.as_dict(), loop.as_dict()
    rt = runner.realtime_report
    return {
        "seconds": seconds,
        "period_us": period * 1e6,
        "floor": fd,
        "loop": ld,
        "added": {k: ld[k] - fd[k] for k in keys},
        "realtime": rt.__dict__ if rt is not None else "not requested",
        "floor_histogram": histogram_rows(before[1] + after[1]),
        "loop_histogram": histogram_rows(runner.hist),
        "floor_decades": decades(before[1] + after[1]),
        "loop_decades": decades(runner.hist),
        "sil_rps": runner.omega / (2 * math.pi),
        "overrun_latch_ticks": latch,
        "would_latch": ld["longest_late_run"] >= latch,
    }


def bench_loop(seconds: float = 60.0) -> dict[str, Any]:
    """`tvsctl bench` figures: loop vs floor jitter, missed ticks and CPU per tick."""
    res = compare(seconds)
    out: dict[str, Any] = {"loop_seconds": seconds}
    for side in ("floor", "loop"):
        for k in ("p50_us", "p99_us", "max_us", "missed_ticks", "rate_hz", "cpu_per_tick_us"):
            out[f"{side}_{k}"] = res[side][k]
    out["loop_work_mean_us"] = res["loop"]["work_mean_us"]
    out["loop_sched_fifo"] = res["realtime"]["sched_fifo"] if isinstance(res["realtime"], dict) else "no"
    return out
