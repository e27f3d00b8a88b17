"""Drift's closed-loop miss: the confirmation on main's design (`ls`) and along identified directions
(`lsd`) on matrix seed 71's case 710084 (R +5 %, 1.17 visible units, refused by the confirmation) and
closedfa's null 520144 (seed 52: an R drift at z 5.0 whose windows trend; the null that would show
whether `lsd` raises a drift alarm). docs/measurements/closedsat.md, "Drift"; with `lscf` (the
drift confirmed with a control function) docs/measurements/closedfix.md.

    nice -n 19 .venv/bin/python scripts/closedsat_drift_probe.py OUT.jsonl [CACHE_DIR] [ls,lsd]
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from tvsd.analysis import matrix as M
from tvsd.analysis import closed_judge as CJ
from tvsd.analysis import closed_plan as CP
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.matrix_open import heldout_gain_skipped
from tvsd.causes import parse_effect
from tvsd.config import load_config
from tvsd.sim.record import record


def main() -> None:
    out = Path(sys.argv[1])
    cache = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("/tmp/closedsat/probe")
    variants = sys.argv[3].split(",") if len(sys.argv) > 3 else ["ls", "lsd"]
    cache.mkdir(parents=True, exist_ok=True)
    c71 = next(c for c in CP.plan_cells(8, (3.0, 10.0, 30.0), 71, 4) if c.seed == 710084)
    n52 = M.cases(n_null=145, reps=0, seed=52, profiles=M.CLOSED_PROFILES)[144]
    for case, cfg in ((c71, CP.case_config(c71)), (n52, M.case_config(load_config(), n52))):
        path = cache / f"case{case.seed}.csv"
        if not path.exists():
            effects = (parse_effect(case.effect),) if case.effect else ()
            record(cfg, path, case.profile, 30.0, effects, case.seed, rps=case.rps or 20.0)
        data = load(path, cfg)
        for variant in variants:
            with heldout_gain_skipped():
                dg = diagnose(data, cfg.plant.v0, rules=CJ.VARIANTS[variant].rules)
            z = {s.cause: round(float(s.z), 3) for s in dg.ranked}
            why = {s.cause: s.why_not[0] for s in dg.ranked if s.why_not}
            row = {
                "seed": case.seed,
                "cause": case.cause,
                "variant": variant,
                "found": dg.cause,
                "z_drift": z.get("drift"),
                "threshold": round(float(dg.outcome.threshold), 3),
                "why_drift": why.get("drift"),
            }
            print(row, flush=True)
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
