"""The speed column's timing against φ's period mean (tvsd/analysis/timing.py), per recording.

    python scripts/speed_timing.py FILE.csv ...            # lag (samples), share, re-timed or not
    python scripts/speed_timing.py --matrix SEED N         # the open matrix's first N cases of SEED
                                                           # (delay and null cases, recorded in a tmp dir)

The doctor re-times ω only where it says "re-timed"; elsewhere its input is what it was before
the rule (docs/measurements/lagref.md).
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from tvsd.analysis import timing
from tvsd.recording.csvfile import read


def report(path: Path) -> bool:
    rec = read(path)
    lag, share = timing.speed_lag(rec.omega, rec.phi, rec.sample_rate_hz)
    moved = timing.off_reference(lag, share)
    print(f"{path.name}\t{rec.sample_rate_hz:g} Hz\tlag {lag:+.3f}\tshare {share:.3f}\t{'re-timed' if moved else '-'}")
    return moved


def matrix(seed: int, count: int) -> list[Path]:
    from tvsd.analysis import matrix as M
    from tvsd.analysis.matrix_open import plan
    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.sim.record import record

    cases = [c for c in plan(2, (1.0, 2.0, 3.0), seed, nulls=2) if c.cause in ("delay", "none")][:count]
    folder = Path(tempfile.mkdtemp(prefix="speed_timing_"))
    out = []
    for case in cases:
        path = folder / f"{case.cause}-{case.size:g}-{case.seed}.csv"
        effects = (parse_effect(case.effect),) if case.effect else ()
        record(M.case_config(load_config(), case), path, case.profile, 30.0, effects, case.seed)
        out.append(path)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--matrix", nargs=2, type=int, metavar=("SEED", "N"))
    a = ap.parse_args()
    files = list(a.files) + (matrix(*a.matrix) if a.matrix else [])
    moved = sum(report(p) for p in files)
    print(f"re-timed: {moved} of {len(files)}")


if __name__ == "__main__":
    main()
