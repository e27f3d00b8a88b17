"""Closed-loop dead zones and drifts sized on their confirmation's rows and columns (branch
closedrules; the clip's were, branch closedfix): each stored row's `seen` re-measured by
closed_judge.seen on the case's recording, the stored one kept as `seen_before`, the answers as
stored (the doctor is not re-run). docs/measurements/closedrules.md, "Sizes".

    nice -n 19 .venv/bin/python scripts/closedrules_sizes.py OUT.jsonl CACHE_DIR CAUSES ROWS.jsonl...
    .venv/bin/python scripts/closedrules_sizes.py --table OUT.jsonl

CAUSES: comma list (deadzone,drift). A case whose recording CACHE_DIR/case{seed}.csv is missing is
recorded there first (the matrix's own recording: same seed, plant, effect, 30 s of identify).
A restart skips the seeds already in OUT. --table: named/cases from X units (the stored `ls`),
before (`seen_before`) and after (`seen`).
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

from tvsd.analysis import closed_judge as CJ
from tvsd.analysis import closed_plan as CP
from tvsd.analysis import matrix as M
from tvsd.analysis.confusion import units
from tvsd.analysis.matrix import clopper_pearson
from tvsd.causes import parse_effect


def measure(out: Path, cache: Path, causes: set[str], sources: list[Path]) -> None:
    from tvsd.sim.record import record

    done = {json.loads(x)["seed"] for x in out.read_text().splitlines()} if out.exists() else set()
    cache.mkdir(parents=True, exist_ok=True)
    for src in sources:
        for line in src.read_text().splitlines():
            r = json.loads(line)
            if r["cause"] not in causes or r["seed"] in done:
                continue
            case = M.Case(**{k.name: r[k.name] for k in dataclasses.fields(M.Case)})
            cfg = CP.case_config(case)
            path = cache / f"case{case.seed}.csv"
            if not path.exists():
                assert case.effect is not None
                part = path.with_suffix(".part")
                record(cfg, part, "identify", 30.0, (parse_effect(case.effect),), case.seed, rps=case.rps)
                part.rename(path)
            keep = {k: r[k] for k in ("ls",) if k in r}
            row = {**dataclasses.asdict(case), **keep, "seen_before": r["seen"]}
            row["seen"] = CJ.seen(path, case, cfg)
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(case.seed, case.cause, r["seen"], "->", row["seen"], r.get("ls"), flush=True)


def table(rows: list[dict[str, Any]]) -> None:
    for cause in sorted({r["cause"] for r in rows}):
        rs = [r for r in rows if r["cause"] == cause]
        before = [{**r, "seen": r["seen_before"]} for r in rs]
        print(f"{cause}: {len(rs)} cases, named (stored `ls`) from X units, before -> after")
        for x in (0.5, 1.0, 2.0, 2.6, 4.0, 8.0):
            cells = []
            for which in (before, rs):
                above = [r for r in which if units(r) >= x]
                k = sum(r["ls"] == cause for r in above)
                lo, hi = clopper_pearson(k, len(above)) if above else (0.0, 1.0)
                cells.append(f"{k}/{len(above)} ({100 * lo:.1f}-{100 * hi:.1f} %)")
            print(f"  >= {x:g} u: {cells[0]} -> {cells[1]}")
        print("  per case: seed, effect, units before -> after, answer")
        for r, b in sorted(zip(rs, before, strict=True), key=lambda p: -units(p[0])):
            print(f"    {r['seed']} {r['effect']} {units(b):.3g} -> {units(r):.3g} {r['ls']}")


if __name__ == "__main__":
    if sys.argv[1] == "--table":
        table([json.loads(x) for f in sys.argv[2:] for x in Path(f).read_text().splitlines() if x.strip()])
    else:
        sources = [Path(p) for p in sys.argv[4:]]
        measure(Path(sys.argv[1]), Path(sys.argv[2]), set(sys.argv[3].split(",")), sources)
