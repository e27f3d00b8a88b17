"""Re-judge open-loop null cases of scripts/doctor_nulls.py by their case seed on the code checked out.

    .venv/bin/python docs/measurements/session5/rejudge.py SEED [SEED ...] > rows.jsonl

A case seed is base × 10000 + k (its row's "seed"): the case is drawn again from the matrix
family exactly as doctor_nulls drew it, analysed without the held-out simulation (the verdict is
the same), and printed as one JSON line. Used on every alarm row of seeds 81 and 82.
"""

import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, "scripts")
import doctor_nulls as DN  # noqa: E402

from tvsd.analysis import matrix as M  # noqa: E402

DN._no_gain()
with tempfile.TemporaryDirectory() as cache:
    for s in map(int, sys.argv[1:]):
        base, k = divmod(s, 10000)
        case = M.cases(k + 1, 0, base)[k]
        r = DN.analyse(case, 30.0, Path(cache))
        print(json.dumps({"seed": s, "found": r["found"], "reason": r.get("reason"), "ranked": r.get("ranked")}), flush=True)
