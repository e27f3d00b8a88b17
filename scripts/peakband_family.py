"""Outsider resonance recordings above the old 50 Hz peak band (docs/measurements/peakband.md):
tests/outsider_bench.py draws at fs 1 kHz (open loop, its own sensor, drive, noise and Q), the
mode's frequency uniform in 50–95 Hz; writes the CSVs, and the names with their truth to stdout.

    peakband_family.py OUTDIR --seed 92 --n 8 --sizes 6,20
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_bench as ob


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--seed", type=int, default=92)
    ap.add_argument("--n", type=int, default=8)
    ap.add_argument("--sizes", default="6,20")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    sizes = [float(x) for x in a.sizes.split(",")]
    for i in range(a.n):
        seed = a.seed * 1000 + i
        s = ob.draw(seed, "resonance", sizes[i % len(sizes)], closed=False)
        s.fs = 1000.0
        s.sensor["tach_fc_hz"] = 1000.0 * np.random.default_rng([seed, 1]).uniform(0.15, 0.35)
        s.truth["frequency_hz"] = float(np.random.default_rng([seed, 2]).uniform(50.0, 95.0))
        path = a.out / f"{s.name}.csv"
        if not path.exists():
            ob.write(path, s, ob.make(s))
        row = {"name": s.name, "size": s.size, "truth": s.truth, "unit": s.unit}
        row.update(sensor=s.sensor["omega"], cpr=s.sensor["cpr"], excitation=s.excitation)
        print(json.dumps(row))


if __name__ == "__main__":
    main()
