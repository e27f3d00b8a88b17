"""colourgain: the colour test on white residuals seen through the doctor's own filters
(docs/measurements/colourgain.md): a white acceleration at the file's rate, its running sum the
recorded speed, the rows the acceleration column's (band filter, central difference, anti-alias,
decimation), judged as the doctor judges (`noise.analyse` with `rowgain.rows_gain`). Per rate and
duration: the colour test's rejections at the doctor's gate (COLOUR_P) and at 0.05, with 95 %
Clopper–Pearson intervals.

    nice -n 19 .venv/bin/python scripts/colourgain_white.py OUT.jsonl [--seeds 40]
    PYTHONPATH=BEFORE nice -n 19 .venv/bin/python scripts/colourgain_white.py B.jsonl   # other code
    .venv/bin/python scripts/colourgain_white.py --summary OUT.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from tvsd.analysis import noise
from tvsd.analysis.matrix import clopper_pearson

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from test_colourgain import judge

RATES = (100.0, 200.0, 500.0, 1000.0)
SECONDS = (20.0, 60.0, 120.0, 300.0, 600.0)


def summary(path: Path) -> None:
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    cells: dict[tuple[float, float], list[float]] = {}
    for row in rows:
        cells.setdefault((row["fs"], row["seconds"]), []).append(row["p"])
    print(f"{'cell':>14} {'n':>4}  p<COLOUR_P (95 % CP)         p<0.05 (95 % CP)          median p")
    for fs in sorted({k[0] for k in cells}):
        group = [(k, v) for k, v in sorted(cells.items()) if k[0] == fs] + [((fs, -1.0), [])]
        pooled: list[float] = []
        for (f, s), ps in group:
            if s < 0:
                ps, label = pooled, f"{f:g} Hz all"
            else:
                pooled += ps
                label = f"{f:g} Hz {s:g} s"
            gate, five = _rate(ps, noise.COLOUR_P), _rate(ps, 0.05)
            print(f"{label:>14} {len(ps):>4}  {gate:<28} {five:<25} {np.median(ps):.3g}")


def _rate(ps: list[float], level: float) -> str:
    k, n = sum(p < level for p in ps), len(ps)
    lo, hi = clopper_pearson(k, n)
    return f"{k}/{n} ({100 * lo:.1f}–{100 * hi:.1f} %)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--summary", action="store_true")
    args = ap.parse_args()
    if args.summary:
        summary(args.out)
        return
    done = set()
    if args.out.exists():
        done = {
            (r["fs"], r["seconds"], r["seed"]) for r in map(json.loads, args.out.read_text().splitlines())
        }
    with args.out.open("a") as fh:
        for fs in RATES:
            for seconds in SECONDS:
                for seed in range(args.seeds):
                    if (fs, seconds, seed) not in done:
                        fh.write(json.dumps(judge(fs, seconds, seed)) + "\n")
                        fh.flush()
    summary(args.out)


if __name__ == "__main__":
    main()
