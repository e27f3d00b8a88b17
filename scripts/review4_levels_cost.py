"""review4: the held-levels projection's cost on a long staircase of distinct levels.

Usage: nice -n 19 .venv/bin/python scripts/review4_levels_cost.py MINUTES HOLD_S
(docs/measurements/review4.md: 4 0.3 before the cap; 10 2.35 at the cap of 256 levels;
docs/measurements/levelsfast.md: the piecewise refit, 1 0.3, 4 0.94, 10 2.35, 10 0.59 at 1024)."""

import resource
import sys
import time

import numpy as np

from tvsd.analysis import command_levels as CL
from tvsd.analysis import memory
from tvsd.analysis.dataset import ROTARY, Dataset
from tvsd.analysis.prep import Band, prepare

FS = 1000.0
minutes = float(sys.argv[1])
hold = float(sys.argv[2])
g = np.random.default_rng(1)
n = int(minutes * 60 * FS)
k = int(n / (hold * FS)) + 1
u = np.repeat(g.uniform(-3.5, 3.5, k), int(hold * FS))[:n]
speed = 20 * u + np.cumsum(g.standard_normal(n)) * 0.01
data = Dataset("lv", np.arange(n) / FS, u, np.cumsum(speed) / FS, speed, FS, 1.0, 0.0, ROTARY, False)
prep = prepare(data, Band())
rows = len(prep.t_rows)
print(
    "rows",
    rows,
    "levels",
    len(CL.held_levels(u)),
    "usable",
    CL.usable_levels(u, False, rows) is not None,
    "memory.columns",
    memory.columns(FS),
)
resid = g.standard_normal(rows)
keep = np.ones(rows, bool)
X = np.column_stack([np.ones(rows), g.standard_normal((rows, 5))])
ar = np.array([1.0, -0.3])
t = time.time()
CL.without_levels(prep, keep, resid, X, ar)
print("secs", time.time() - t, "maxrss MiB", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
