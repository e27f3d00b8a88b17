"""Why the closed-loop matrix's cases of a cause were not named: per case the least-squares z,
the check that refused it (verdict.WHY's code), and the instrumented confirmation's z for the
cause against its gate (with the number of its options there), from cached recordings.

    python scripts/closed_refusals.py 'ROWS*.jsonl' CACHE_DIR deadzone,saturation [miss]

ROWS: tvsd.analysis.matrix_closed --cells rows (their plan seeds); CACHE_DIR: its --cache, with
case<seed>.csv; `miss`: only the rows whose answer was not the true cause. One JSON line each.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import sys
from pathlib import Path
from typing import Any

from tvsd.analysis import calibrate as C
from tvsd.analysis import doctor
from tvsd.analysis import matrix as M
from tvsd.analysis import closed_plan as CP
from tvsd.analysis.dataset import load
from tvsd.analysis.matrix_open import _no_gain


def main() -> None:
    _no_gain()
    rows = [json.loads(line) for g in glob.glob(sys.argv[1]) for line in Path(g).read_text().splitlines()]
    cache, causes = Path(sys.argv[2]), sys.argv[3].split(",")
    only_miss = sys.argv[4:5] == ["miss"]
    calls: list[tuple[Any, dict[str, int]]] = []
    test_all = C.test_all

    def logged(design: Any, seed: int = 0, **kw: Any) -> Any:
        out = test_all(design, seed=seed, **kw)
        calls.append((out, {k: len(v) for k, v in design.options.items()}))
        return out

    doctor.C.test_all = logged  # the first call is least squares, the second the instruments
    for r in rows:
        if r["cause"] not in causes or (only_miss and r["ls"] == r["cause"]):
            continue
        case = M.Case(**{f.name: r[f.name] for f in dataclasses.fields(M.Case)})
        cfg = CP.case_config(case)
        calls.clear()
        dg = doctor.diagnose(load(cache / f"case{case.seed}.csv", cfg), cfg.plant.v0)
        s = next((s for s in dg.ranked if s.cause == r["cause"]), None)
        iv = None
        if len(calls) > 1:
            out, n_opts = calls[1]
            t = next((t for t in out.tested if t.cause == r["cause"]), None)
            iv = [round(t.z, 2) if t else None, round(out.threshold, 2), n_opts.get(r["cause"], 0)]
        row = {
            "seed": case.seed, "cause": r["cause"], "size": r["size"], "sv": r["sigma_v"],
            "seen": r["seen"], "effect": r["effect"], "found": dg.cause,
            "z": round(s.z, 2) if s else None, "why": s.why_not[0] if s and s.why_not else None,
            "iv": iv,
        }  # fmt: skip
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
