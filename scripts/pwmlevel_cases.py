"""The outsider cases branch pwmlevel can reach: open loop, a V or duty command held on levels,
a tach speed beside an encoder (docs/measurements/pwmlevel.md).

    .venv/bin/python scripts/pwmlevel_cases.py SET --seed 12 [--reps 2 --nulls 80 --sizes 6,20]

Writes each such case's CSV into SET (if missing) and prints `NAME CAUSE SIZE`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_bench as ob

from tvsd.analysis import command_levels
from tvsd.analysis.dataset import load
from tvsd.config import load_config


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("set", type=Path)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--nulls", type=int, default=80)
    ap.add_argument("--sizes", default="6,20")
    a = ap.parse_args(argv)
    a.set.mkdir(parents=True, exist_ok=True)
    cfg = load_config()
    for seed, cause, m in ob.plan(a.seed, a.reps, a.nulls, tuple(float(x) for x in a.sizes.split(","))):
        s = ob.draw(seed, cause, m)
        if s.excitation == "closed" or s.unit not in ("V", "duty") or s.sensor["omega"] == "diff":
            continue
        path = a.set / f"{s.name}.csv"
        if not path.exists():
            ob.write(path, s, ob.make(s))
        u = load(path, cfg).u
        if command_levels.usable_levels(u, False, len(u) // 4) is None:
            continue
        print(s.name, cause, m, s.excitation, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
