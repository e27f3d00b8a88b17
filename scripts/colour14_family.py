"""Outsider draws of one class, the doctor in process: the colour test's answer on each
(docs/measurements/colour14.md).

    nice -n 19 .venv/bin/python scripts/colour14_family.py OUT.jsonl --class coarse --n 30 --seed 140000 \
        [--cause colored_noise:6] [--shard 0/2]
    .venv/bin/python scripts/colour14_family.py --summary OUT.jsonl ...

Classes (each draw keeps the outsider's plant, noise and command, with these set):
- `coarse`: o14033's — V drive, 8-bit PWM, 256-count encoder difference (declared), 2 kHz,
  open-loop staircase, 30 s;
- `prbs500`: o14073's — V drive, 10-bit PWM, 8192-count encoder difference, 500 Hz, PRBS, 60 s;
- `coarse1k`: as `coarse` at 1 kHz with 1024 counts and a staircase or a PRBS.
The before code: the same command with PYTHONPATH=BEFORE (a `git archive integ3`).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_classes as oc
from scipy.stats import beta


def cp95(k: int, n: int) -> tuple[float, float]:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def summary(paths: list[str]) -> None:
    rows = [json.loads(line) for p in paths for line in Path(p).read_text().splitlines()]
    by: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(f"{r['class']} {r['truth']}", []).append(r)
    for key, rs in sorted(by.items()):
        n = len(rs)
        col = sum(r["cause"] == "colored_noise" for r in rs)
        other = sum(r["cause"] not in ("none", "colored_noise", "refused") for r in rs)
        lo, hi = cp95(col, n)
        print(
            f"{key}: colored_noise {col}/{n} ({100 * col / n:.1f} %, CP {100 * lo:.1f}–{100 * hi:.1f} %), "
            f"other causes {other}, refused {sum(r['cause'] == 'refused' for r in rs)}"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="+")
    ap.add_argument("--class", dest="cls", default="coarse", choices=sorted(oc.CLASSES))
    ap.add_argument("--n", type=int, default=30)
    ap.add_argument("--seed", type=int, default=140000)
    ap.add_argument("--cause", default=None, help="cause:size, e.g. colored_noise:6 (default: nulls)")
    ap.add_argument("--shard", default="0/1")
    ap.add_argument("--summary", action="store_true")
    a = ap.parse_args(argv)
    if a.summary:
        summary(a.out)
        return 0
    cause, size = (a.cause.split(":")[0], float(a.cause.split(":")[1])) if a.cause else ("none", 0.0)
    i, k = (int(x) for x in a.shard.split("/"))
    tmp = Path(tempfile.mkdtemp(prefix="c14fam"))
    with open(a.out[0], "a") as fh:
        for case in oc.v_seeds(a.seed, a.n)[i::k]:
            s = oc.spec_of(a.cls, case, cause, size)
            r = {"class": a.cls, "seed": case, "truth": f"{cause}:{size:g}", **oc.run_one(s, tmp)}
            fh.write(json.dumps(r) + "\n")
            fh.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
