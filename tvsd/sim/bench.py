"""Benchmarks of the model and controller kernels (`tvsctl bench`).

Figures are wall-clock on the machine that runs them; each is the best of a few repeats, which
removes the shared machine's interference from the estimate of what the code costs.
"""

from __future__ import annotations

import math
import subprocess
import sys
import time

import numpy as np
from numba import njit

from tvsd.causes import parse_effects
from tvsd.config import load_config
from tvsd.control.law import robust_law
from tvsd.control.setup import Setup
from tvsd.sim import runs


@njit(cache=True, nogil=True)
def _law_loop(n: int, eps: np.ndarray) -> float:
    acc = 0.0
    m = len(eps)
    for k in range(n):
        e = eps[k % m]
        acc += robust_law(e, -0.5 * e, 3.5, 6.0, 4.0, 52.0, 12.0)
    return acc


def control_step_ns(n: int = 2_000_000, repeats: int = 5) -> float:
    """Cost of one evaluation of the robust law inside a compiled loop."""
    eps = np.linspace(-0.5, 0.5, 1001)
    _law_loop(10, eps)
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        _law_loop(n, eps)
        best = min(best, time.perf_counter() - t0)
    return best / n * 1e9


def sim_realtime_factor(sim_seconds: float = 20.0, repeats: int = 3) -> dict[str, float]:
    """Simulated seconds per wall second: 10 kHz plant + robust law, OU vibration and imbalance on."""
    cfg = load_config(params="default")
    setup = Setup.from_config(cfg, effects=parse_effects(["imbalance:amplitude=6e-5,phase=0.5"]))
    runs.spin(setup, 25.0, 0.01)  # compile / load the cache outside the timing
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        runs.spin(setup, 25.0, sim_seconds, decim=10)
        best = min(best, time.perf_counter() - t0)
    steps = sim_seconds / setup.dt
    return {"sim_realtime_factor": sim_seconds / best, "plant_step_ns": best / steps * 1e9}


def cli_warm_start_s(repeats: int = 3) -> float:
    """Wall time of a warm `tvsctl sim step` (numba cache loaded, not compiled)."""
    cmd = [sys.executable, "-m", "tvsd.cli.main", "sim", "step", "--ref-deg", "5", "--json"]
    subprocess.run(cmd, check=True, capture_output=True)
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        best = min(best, time.perf_counter() - t0)
    return best
