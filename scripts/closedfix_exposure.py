"""Re-measure the closed-loop clips' `seen` (tvsd.analysis.exposure) on their cached recordings:
a clip's exposed units on the rows and columns of its confirmation (branch closedfix), the
answers kept as stored. docs/measurements/closedfix.md, "The clip's exposed units".

    nice -n 19 .venv/bin/python scripts/closedfix_exposure.py ROWS.jsonl CACHE_DIR OUT.jsonl

Each row of ROWS (tvsd.analysis.matrix_closed's) is written to OUT with `seen` re-measured on
CACHE_DIR/case{seed}.csv and the stored one kept as `seen_before`.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from tvsd.analysis import matrix as M
from tvsd.analysis import closed_judge as CJ
from tvsd.analysis import closed_plan as CP


def main() -> None:
    rows, cache, out = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
    with out.open("w") as f:
        for line in rows.read_text().splitlines():
            if not line.strip():
                continue
            r = json.loads(line)
            case = M.Case(**{k.name: r[k.name] for k in dataclasses.fields(M.Case)})
            r["seen_before"] = r["seen"]
            r["seen"] = CJ.seen(cache / f"case{case.seed}.csv", case, CP.case_config(case))
            print(
                case.seed,
                r["seen_before"].get("exposed_units"),
                "->",
                r["seen"].get("exposed_units"),
                flush=True,
            )
            f.write(json.dumps(r) + "\n")


if __name__ == "__main__":
    main()
