"""Which cases of an outsider set the held-level projection or the count-grid reading can change
(tvsd.analysis.command_levels, count_grid.read_step): the others take the same code path as before.

    .venv/bin/python scripts/outsider_changed.py SET 'ROWS*.jsonl' > names.txt

A case can change when its command is held on levels in open loop (usable_levels is not None) or
when its speed's grid is read from the data (no `# encoder_counts_per_rev:`) and read differently.
"""

from __future__ import annotations

import glob
import json
import sys
from pathlib import Path

import numpy as np

from tvsd.analysis import count_grid
from tvsd.analysis.command_levels import usable_levels
from tvsd.analysis.prep import Band
from tvsd.recording.csvfile import read as read_recording


def _smallest_gap_step(omega: np.ndarray) -> float | None:
    """integ3's reading: the smallest printed gap, confirmed on the grid."""
    levels = np.unique(np.abs(omega))
    if len(levels) > len(omega) // 10:
        return None
    gaps = np.diff(levels)
    gaps = gaps[gaps > 1e-5 * max(float(levels[-1]), 1e-12)]
    if len(gaps) + 1 < count_grid.MIN_LEVELS:
        return None
    step = float(np.min(gaps))
    return step if count_grid.on_grid(omega, step) else None


def main() -> int:
    set_dir, pattern = Path(sys.argv[1]), sys.argv[2]
    for f in sorted(glob.glob(pattern)):
        for line in Path(f).read_text().splitlines():
            name = json.loads(line)["name"]
            rec = read_recording(set_dir / f"{name}.csv")
            u = rec.u * float(rec.meta.get("u_scale", 1.0))
            n_rows = len(u) // Band().decim
            levels = usable_levels(u, "omega_ref" in rec.extra, n_rows) is not None
            undeclared = "encoder_counts_per_rev" not in rec.meta
            grid = undeclared and (count_grid.read_step(rec.omega) is None) != (
                _smallest_gap_step(rec.omega) is None
            )
            if levels or grid:
                print(name, "levels" * levels, "grid" * grid, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
