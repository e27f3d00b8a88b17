"""Two causes in one recording: does the doctor's forward selection name both? Resumable.

Each case is a case of the randomised matrix (tvsd.analysis.matrix: seeded plant, excitation,
σv) with its cause A at a matrix size, and an imbalance added at its own size (matrix units:
m × 0.5·J N·m, phase drawn). One JSON line per case goes to --out (the top cause, every cause
named), so an interrupted run resumes; the summary says how often both were named, how often
the top one was one of the two, and how often a cause that is not there was named too:

    nice -n 5 .venv/bin/python scripts/doctor_two_causes.py --first friction_asymmetry \\
        --sizes 10,30 --imbalance 10 --reps 3 --seed 41 --out two.jsonl --cache /tmp/two
    .venv/bin/python scripts/doctor_two_causes.py --summary two.jsonl
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.analysis import matrix as M


def cases(
    first: str, sizes: set[float], imbalance: float, reps: int, seed: int, loop: str = "open"
) -> list[tuple[M.Case, str]]:
    """(case with cause `first`, the imbalance's effect text): the matrix's open-loop cases, or
    its closed-loop ones (identify's excitation, scanning at the speed the plant holds)."""
    out = []
    profiles = M.OPEN_PROFILES if loop == "open" else M.CLOSED_PROFILES
    for c in M.cases(0, reps, seed, causes=(first,), profiles=profiles):
        if c.size not in sizes:
            continue
        g = np.random.default_rng([seed, c.seed, 7])
        amp = imbalance * 0.5 * c.plant["J"]
        out.append((c, f"imbalance:amplitude={amp:.6g},phase={g.uniform(-3, 3):.3f}"))
    return out


def analyse(case: M.Case, extra: str, seconds: float, folder: Path) -> dict[str, Any]:
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.sim.record import record

    cfg = M.case_config(load_config(), case)
    path = folder / f"two-{case.profile}-{case.seed}.csv"
    assert case.effect is not None
    if not path.exists():
        tmp = path.with_suffix(".part")
        effects = (parse_effect(case.effect), parse_effect(extra))
        record(cfg, tmp, case.profile, seconds, effects, case.seed, rps=case.rps or 20.0)
        tmp.rename(path)
    row: dict[str, Any] = {
        "seed": case.seed,
        "first": case.cause,
        "size": case.size,
        "effects": [case.effect, extra],
        "profile": case.profile,
        "sigma_v": case.sigma_v,
    }
    t0 = time.process_time()
    try:
        dg = diagnose(load(path, cfg), cfg.plant.v0)
        row["found"] = dg.cause
        row["causes"] = [[c.cause, round(c.z, 3), round(c.threshold, 3), c.step] for c in dg.causes]
        imb = [c.effect for c in dg.causes if c.cause == "imbalance"]
        row["imbalance"] = {k: v for k, v in imb[0].items() if isinstance(v, float)} if imb else None
    except Exception as exc:  # a bad case is a result too
        row["found"] = f"error: {type(exc).__name__}: {exc}"[:160]
        row["causes"] = []
    row["cpu_s"] = time.process_time() - t0
    return row


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    both = [r for r in rows if {r["first"], "imbalance"} <= {c[0] for c in r["causes"]}]
    top_ok = sum(r["found"] in (r["first"], "imbalance") for r in rows)
    extra = [r for r in rows if {c[0] for c in r["causes"]} - {r["first"], "imbalance"}]
    lo, hi = M.clopper_pearson(len(both), n) if n else (math.nan, math.nan)
    by_size: dict[str, list[int]] = {}
    for r in rows:
        k = f"{r['first']}@{r['size']:g}x"
        by_size.setdefault(k, [0, 0])
        by_size[k][0] += r in both
        by_size[k][1] += 1
    return {
        "cases": n,
        "both_named": len(both),
        "both_ci95_pct": [round(100 * lo, 1), round(100 * hi, 1)],
        "top_is_one_of_the_two": top_ok,
        "a_cause_not_there_named": len(extra),
        "extra_named": [[r["seed"], [c[0] for c in r["causes"]]] for r in extra],
        "by_size": {k: f"{v[0]}/{v[1]}" for k, v in sorted(by_size.items())},
        "cpu_s_median": float(np.median([r["cpu_s"] for r in rows])) if rows else math.nan,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--first", default="friction_asymmetry", help="the case's own cause (matrix)")
    ap.add_argument("--sizes", default="10,30", help="its matrix sizes")
    ap.add_argument("--imbalance", type=float, default=10.0, help="the added imbalance's matrix size")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--loop", choices=("open", "closed"), default="open")
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/two_causes"))
    ap.add_argument("--summary", type=Path, nargs="+")
    a = ap.parse_args()
    if a.summary:
        rows = [json.loads(x) for f in a.summary for x in f.read_text().splitlines() if x.strip()]
        print(json.dumps(summary(rows)))
        return 0
    if a.out is None:
        ap.error("--out FILE is needed (one JSON line per case; the run resumes from it)")
    done = set()
    if a.out.exists():
        done = {json.loads(x)["seed"] for x in a.out.read_text().splitlines() if x.strip()}
    a.cache.mkdir(parents=True, exist_ok=True)
    sizes = {float(x) for x in a.sizes.split(",")}
    for case, extra in cases(a.first, sizes, a.imbalance, a.reps, a.seed, a.loop):
        if case.seed in done:
            continue
        row = analyse(dataclasses.replace(case), extra, a.seconds, a.cache)
        with a.out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(case.seed, row["found"], [c[0] for c in row["causes"]], f"{row['cpu_s']:.1f}s", file=sys.stderr)
    rows = [json.loads(x) for x in a.out.read_text().splitlines() if x.strip()]
    print(json.dumps(summary(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
