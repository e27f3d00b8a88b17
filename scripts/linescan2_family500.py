"""The spectral tests' nulls of scripts/bandfloor_peaks.py's family, only the cases at one rate.

    nice -n 19 .venv/bin/python scripts/linescan2_family500.py --seed 1202 --nulls 317 --fs 500 --out OUT.jsonl
    .venv/bin/python scripts/bandfloor_peaks.py --summary OUT.jsonl

The decimation at 500 Hz changed (×4 → ×2, docs/measurements/linescan2.md), so only those
cases' rows changed; the rest of a stored run (docs/measurements/peakevid/) stands. `--mix` as
peakevid ran them (excitation and gaps by the index); rows as bandfloor_peaks writes them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import bandfloor_peaks as bp
import quantisation_nulls as qn


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--nulls", type=int, required=True)
    ap.add_argument("--fs", type=float, default=500.0)
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    done = set()
    if a.out.exists():
        done = {json.loads(x)["i"] for x in a.out.read_text().splitlines() if x.strip()}
    with a.out.open("a") as fh:
        for i in range(a.nulls):
            null = dataclasses.replace(qn.draw(np.random.default_rng([a.seed, i])))
            if null.fs != a.fs or i in done:
                continue
            fh.write(json.dumps(bp.case(a.seed, i, 0.0, 0.0, 30.0, 90.0, False, True)) + "\n")
            fh.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
