"""Compare closed-loop matrix rows before/after a change: every key but the timings (`*_s`) as
JSON text, per case seed (docs/measurements/closedrules.md).

    python scripts/closedrules_cmp_rows.py BEFORE.jsonl AFTER.jsonl
"""

import json
import sys
from pathlib import Path


def load(path: str) -> dict[int, str]:
    out = {}
    for line in Path(path).read_text().splitlines():
        r = json.loads(line)
        out[r["seed"]] = json.dumps({k: v for k, v in r.items() if not k.endswith("_s")})
    return out


a, b = load(sys.argv[1]), load(sys.argv[2])
for seed in sorted(set(a) | set(b)):
    same = a.get(seed) == b.get(seed)
    row = json.loads(a.get(seed) or b[seed])
    print(seed, "identical" if same else "DIFFERS", {k: row[k] for k in ("ls", "ls0") if k in row})
