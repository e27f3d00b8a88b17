"""Benchmark of the model doctor (`tvsctl bench --only doctor`).

1. `tvsctl analyze` of a 60 s, 1 kHz recording, each run a child process measured by wait4: wall,
   CPU (user + system: what a loaded machine charges) and peak resident memory of that child
   alone (tvsd.analysis.benchchild). Cold: numba's cache empty (NUMBA_CACHE_DIR pointed at a
   fresh directory), so the compiled kernels are built; warm: the same directory again, loaded.
   An open-loop staircase with a hidden dead zone, and a closed-loop scanning recording with
   tvsctl identify's excitation.
2. The randomised matrix (tvsd.analysis.matrix), open and closed loop, its cases spread over
   worker processes: every case is seeded and BLAS runs on one thread, so the answers are the
   serial run's (tests/test_doctor_bench.py); `cases` keeps a spread subset for a quick run.
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_all_start_methods, get_context
from pathlib import Path
from statistics import median
from typing import Any

from tvsd.analysis.benchchild import Child
from tvsd.analysis.benchchild import run_child as _child

WARM_REPEATS = 3
RECORDINGS = {  # figure key -> (profile, effect)
    "analyze_60s_open": ("steps", "deadzone:u0=0.8"),
    "analyze_60s_closed": ("identify", None),
}


def bench_doctor(
    cases: int | None = None,
    workers: int | None = None,
    progress: Callable[[str], None] | None = None,
    n_null: int = 50,
    reps: int = 3,
    seed: int = 0,
) -> dict[str, Any]:
    """The 60 s timings, then the randomised matrix (tvsd.analysis.matrix: `n_null` nulls and
    `reps` effect cases per cause and size; all its cases, or `cases` of each), open loop and
    closed loop (scanning with tvsctl identify's excitation)."""
    say = progress or (lambda _msg: None)
    out: dict[str, Any] = {"doctor_load_avg_at_start": round(os.getloadavg()[0], 1)}  # wall reads by it
    for key, (profile, effect) in RECORDINGS.items():
        say(f"timing tvsctl analyze on a 60 s {profile} recording (cold, then warm ×{WARM_REPEATS})")
        out.update(bench_analyze(key, profile, effect))
    for loop in ("open", "closed"):
        say(f"matrix, {loop} loop")
        out.update(run_matrix(loop, cases=cases, workers=workers, n_null=n_null, reps=reps, seed=seed))
    return out


# What `tvsctl analyze` imports (tvsd/cli/analyze.py's _run): a measured analysis's prelude, so that
# its own allocations are measured above the interpreter's (tvsd.analysis.benchchild). Source, not
# a function here: importing this module would add its own imports to the child's.
_IMPORT_DOCTOR = """
import tvsd.cli.analyze, tvsd.cli.main
from tvsd.analysis import dataset, doctor, lyapunov, memory, noise, prep, report, summary, window
"""


def load_doctor_kernels() -> None:
    """Load the doctor's numba kernels (compiled into the cache when it is cold) with the argument
    types the doctor gives them: the warm-up before an analysis is timed. Not in the measured
    analysis's prelude: loaded there, the kernels (15 MiB) sit under the analysis's peak, which
    `tvsctl analyze` alone reaches before it loads them (memflake.md)."""
    import numpy as np

    from tvsd.analysis import lyapunov
    from tvsd.analysis.simulate import ReducedModel, no_effect, simulate

    t, zeros = np.arange(8) / 1000.0, np.zeros(8)
    simulate(ReducedModel(1e-4, 1e-3, 0.01, 0.0, 1.0, 0.0, 1.0, 0.0), t, zeros, no_effect(), zeros, zeros)
    lyapunov.log_stretch(np.zeros((3, 2, 2)), np.zeros(3), np.ones(2))


_LOAD_KERNELS = "from tvsd.analysis.bench import load_doctor_kernels\nload_doctor_kernels()"


def bench_analyze(
    key: str = "analyze_60s_open", profile: str = "steps", effect: str | None = None, seconds: float = 60.0
) -> dict[str, float]:
    cli = [sys.executable, "-m", "tvsd.cli.main"]
    with tempfile.TemporaryDirectory() as tmp:
        rec = Path(tmp) / "bench.csv"
        record = [*cli, "sim", "record", "--out", str(rec), "--profile", profile]
        record += ["--seconds", f"{seconds:g}", "--seed", "7"]
        if effect:
            record += ["--effect", effect]
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba-cache")}
        _child(record, env)
        analyze = [*cli, "analyze", str(rec), "--json", "--quiet"]
        cold = _child(analyze, env)
        warm = [_child(analyze, env) for _ in range(WARM_REPEATS)]
    return {
        f"{key}_wall_s": median(w.wall_s for w in warm),
        f"{key}_cpu_s": median(w.cpu_s for w in warm),
        f"{key}_peak_rss_mib": max(w.peak_rss_mib for w in warm),
        f"{key}_cold_wall_s": cold.wall_s,
        f"{key}_cold_cpu_s": cold.cpu_s,
    }


def _one_blas_thread() -> None:
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def _case(args: tuple[Any, float, str]) -> dict[str, Any]:
    from tvsd.analysis.matrix import run_case

    case, seconds, tmp = args
    return run_case(case, seconds, Path(tmp))


def spread(items: list[Any], n: int | None) -> list[Any]:
    """n items spread evenly over the list (nulls and every cause and size), or all of them."""
    if n is None or n >= len(items):
        return list(items)
    step = len(items) / n
    return [items[int(k * step)] for k in range(n)]


def run_matrix(
    loop: str = "open",
    cases: int | None = None,
    workers: int | None = None,
    n_null: int = 50,
    reps: int = 3,
    seconds: float = 30.0,
    seed: int = 0,
) -> dict[str, Any]:
    """tvsd.analysis.matrix.run's figures, its cases over `workers` processes (default: one per
    core), keyed doctor_<loop>_…, with the matrix's wall time, CPU time and worker count."""
    from tvsd.analysis import matrix as M

    profiles = M.OPEN_PROFILES if loop == "open" else M.CLOSED_PROFILES
    picked = spread(M.cases(n_null, reps, seed, None, profiles), cases)
    workers = max(1, min(workers or os.cpu_count() or 1, len(picked)))
    cpu0 = _cpu_s()
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        jobs = [(c, seconds, tmp) for c in picked]
        if workers == 1:
            _one_blas_thread()
            results = [_case(j) for j in jobs]
        else:
            # fork: the workers start with the modules loaded, and a caller's script needs no
            # `if __name__ == "__main__"` guard (spawn would run it again in each worker).
            ctx = get_context("fork" if "fork" in get_all_start_methods() else "spawn")
            with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_one_blas_thread) as pool:
                results = list(pool.map(_case, jobs))
    wall = time.perf_counter() - t0
    key = f"doctor_{loop}"
    figures = M.summarise(results, key, wall)
    figures[f"{key}_workers"] = workers
    figures[f"{key}_cpu_s"] = _cpu_s() - cpu0
    return figures


def _cpu_s() -> float:
    """CPU seconds of this process and its finished children (the pool's workers once joined)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


# A recording at a given rate: the default config with its SIL measurement's sample rate replaced.
_RECORD_AT = """
import dataclasses, sys
from pathlib import Path
from tvsd.causes import parse_effect
from tvsd.config import load_config
from tvsd.sim.record import record
out, seconds, rate = Path(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
cfg = load_config()
sil = cfg.sil_or_default
sil = dataclasses.replace(sil, measurement=dataclasses.replace(sil.measurement, sample_rate_hz=rate))
cfg = dataclasses.replace(cfg, sil=sil)
record(cfg, out, "steps", seconds, (parse_effect("deadzone:u0=0.8"),), seed=7)
"""

LONG_SIZES = ((60.0, 1000.0), (120.0, 2000.0))  # (seconds, Hz); 1 h at 1 and 2 kHz on request


def _mib(x: float, digits: int) -> float | None:
    """A memory figure rounded; None (JSON null) when the child did not report it (benchchild's
    NaN: round(NaN) raises, and NaN is no JSON)."""
    if not math.isfinite(x):
        return None
    return round(x) if digits == 0 else round(x, digits)


def bench_long(
    sizes: tuple[tuple[float, float], ...] = LONG_SIZES, progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """`tvsctl analyze` (warm: the kernels loaded from numba's cache, filled before the first)
    on a SIL staircase with a 0.8 V dead zone per (seconds, Hz): wall, CPU and the child's own
    peak RSS (what a user sees), and what the analysis itself allocated (`doctor_mib`: the peak
    of its anonymous memory above the same process's once `tvsctl analyze`'s imports are done,
    which a machine's page cache does not change), per minute of recording too (long_figures),
    each beside its estimate (tvsd.analysis.memory). One run each: the 1 h ones take minutes. A
    size the doctor refuses (not enough memory) is reported with its reason."""
    from tvsd.analysis import memory
    from tvsd.analysis.prep import Band

    say = progress or (lambda _msg: None)
    cli = [sys.executable, "-m", "tvsd.cli.main"]
    out: dict[str, Any] = {"doctor_long_load_avg_at_start": round(os.getloadavg()[0], 1)}
    measured: dict[float, list[tuple[float, float]]] = {}  # rate -> (seconds, doctor_mib)
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": str(Path(tmp) / "numba-cache")}
        _child([sys.executable, "-c", _LOAD_KERNELS], env)  # compiles the kernels into the cache
        for seconds, rate in sizes:
            key = f"doctor_long_{seconds:g}s_{rate / 1000:g}khz"
            rec = Path(tmp) / f"{key}.csv"
            n = round(seconds * rate)
            say(f"recording {seconds:g} s at {rate:g} Hz, then tvsctl analyze on it")
            _child([sys.executable, "-c", _RECORD_AT, str(rec), f"{seconds:g}", f"{rate:g}"], env)
            out[f"{key}_estimate_mib"] = round(memory.estimate_mib(n, rate, Band()))
            out[f"{key}_doctor_estimate_mib"] = round(memory.doctor_mib(n, rate, Band()), 1)
            try:
                run = _child([*cli, "analyze", str(rec), "--json", "--quiet"], env, prelude=_IMPORT_DOCTOR)
            except RuntimeError as exc:  # refused (exit 2) or failed: said, not a crash of the suite
                out[f"{key}_refused"] = str(exc)[-300:]
                rec.unlink()
                continue
            rec.unlink()
            out.update(long_figures(key, run, seconds, rate))
            measured.setdefault(rate, []).append((seconds, run.own_mib))
    for rate, runs in measured.items():
        out.update(slope_figure(rate, runs))
    return out


def slope_figure(rate: float, runs: list[tuple[float, float]]) -> dict[str, float | None]:
    """`doctor_mib`'s growth per minute between the two longest sizes measured at one rate: the
    per-minute figure with nothing taken from the estimate (the null and the fixed parts cancel
    once both sizes are past the null's bound, 40 s at 1 kHz); nothing from one size."""
    runs = sorted(r for r in runs if math.isfinite(r[1]))
    if len(runs) < 2 or runs[-1][0] == runs[-2][0]:
        return {}
    (s1, d1), (s2, d2) = runs[-2:]
    return {f"doctor_long_{rate / 1000:g}khz_slope_mib_per_min": _mib((d2 - d1) / ((s2 - s1) / 60.0), 1)}


def long_figures(key: str, run: Child, seconds: float, rate: float) -> dict[str, float | None]:
    """One size's figures. `mib_per_min` is the part of the analysis's own allocation that grows
    with the record, per minute: `doctor_mib` less the line scan's null (bounded whatever the
    length; memory.null_mib, what tracemalloc measures of it), over the minutes — the figure that
    says how long a recording fits in a given memory, beside the estimate's (the refusal's
    "MiB per minute", memory.copies_mib). It was (peak RSS − memory.BASE_MIB) per minute, which
    carries the page cache: +93 MiB/min in one venv and −61 in another at 20 s (memflake.md)."""
    from tvsd.analysis import memory
    from tvsd.analysis.prep import Band

    n, minutes = round(seconds * rate), seconds / 60.0
    return {
        f"{key}_wall_s": round(run.wall_s, 2),
        f"{key}_cpu_s": round(run.cpu_s, 2),
        f"{key}_peak_rss_mib": _mib(run.peak_rss_mib, 0),
        f"{key}_doctor_mib": _mib(run.own_mib, 1),
        f"{key}_base_anon_mib": _mib(run.base_anon_mib, 1),
        f"{key}_mib_per_min": _mib((run.own_mib - memory.null_mib(n, Band())) / minutes, 1),
        f"{key}_estimate_mib_per_min": round(memory.copies_mib(n, rate, Band()) / minutes, 1),
    }
