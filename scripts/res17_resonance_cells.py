"""The randomised matrix's resonance cells (tvsd.analysis.matrix, `tvsctl bench --only doctor`'s
cases restricted to `resonance`), open and closed loop, recorded once into --cache and judged by
whichever tvsd is first on the path (docs/measurements/res17.md: this branch against integ3's
tree on PYTHONPATH, the same recordings):

    nice -n 19 .venv/bin/python scripts/res17_resonance_cells.py --loop closed --seed 0 --reps 3 \
        --cache /tmp/res17cells --out cells-closed.jsonl
    .venv/bin/python scripts/res17_resonance_cells.py --summary cells-closed.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import doctor_nulls as dn

from tvsd.analysis import matrix as M


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loop", choices=sorted(dn.LOOP_PROFILES), default="closed")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--cache", type=Path)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--summary", type=Path, nargs="+")
    a = ap.parse_args()
    if a.summary:
        rows = [json.loads(x) for f in a.summary for x in f.read_text().splitlines() if x.strip()]
        by: dict[str, list[int]] = {}
        for r in rows:
            k = f"{r['profile']} {r['size']:g}x"
            by.setdefault(k, [0, 0])
            by[k][0] += r["found"] == "resonance"
            by[k][1] += 1
        found = sum(v[0] for v in by.values())
        print(
            json.dumps(
                {
                    "resonance_named": f"{found}/{len(rows)}",
                    **{k: f"{v[0]}/{v[1]}" for k, v in sorted(by.items())},
                }
            )
        )
        return 0
    if a.out is None or a.cache is None:
        ap.error("--out and --cache are needed")
    dn._no_gain()
    done = {json.loads(x)["seed"] for x in a.out.read_text().splitlines()} if a.out.exists() else set()
    a.cache.mkdir(parents=True, exist_ok=True)
    todo = M.cases(0, a.reps, a.seed, causes=("resonance",), profiles=dn.LOOP_PROFILES[a.loop])
    for case in [dn.with_speed(c) for c in todo]:
        if case.seed in done:
            continue
        row = dn.analyse(case, 30.0, a.cache)
        with a.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(case.seed, case.profile, case.size, row["found"], flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
