"""Re-analyse stored open-matrix rows on the current rule, from their cached recordings.

Only a row where some deterministic cause's z passed the gate can change when a confirmation
(the out-of-sample check, the drift's windows) changes: the others are copied as they are. The
re-analysed rows go first where the old answer was a miss, then drift / friction asymmetry /
imbalance, then the rest, so that a batch cut short has done the informative ones; a restart
skips the seeds already in the output files.

    nice -n 5 .venv/bin/python scripts/matrix_reanalyse.py 0/2 seed34=/tmp/ol/cache34 seed33=... &
    nice -n 5 .venv/bin/python scripts/matrix_reanalyse.py 1/2 seed34=/tmp/ol/cache34 seed33=... &

reads docs/measurements/open-matrix/SRC.w*.jsonl, writes heldout-SRC.wI.jsonl beside them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from tvsd.analysis import matrix as M
from tvsd.analysis.matrix_open import run

D = Path(__file__).resolve().parent.parent / "docs" / "measurements" / "open-matrix"
FIELDS = ("seed", "cause", "size", "noise_units", "effect", "profile", "sigma_v", "plant", "rps")


def main() -> None:
    w, nw = map(int, sys.argv[1].split("/"))
    todo = []
    for arg in sys.argv[2:]:
        src, cache = arg.split("=", 1)
        rows = sorted(
            (json.loads(x) for f in sorted(D.glob(f"{src}.w*.jsonl")) for x in f.read_text().splitlines()),
            key=lambda r: r["seed"],
        )
        out = D / f"heldout-{src}.w{w}.jsonl"
        done = {json.loads(x)["seed"] for x in out.read_text().splitlines()} if out.exists() else set()
        with out.open("a") as f:
            for r in rows[w::nw]:
                if r["seed"] in done:
                    continue
                why = r["ls_why"]
                if not any(v > why["threshold"] for k, v in why["z"].items() if k != "colored_noise"):
                    f.write(json.dumps(r) + "\n")
                    continue
                prio = (
                    0
                    if r["ls"] != r["cause"]
                    else 1
                    if r["cause"] in ("drift", "friction_asymmetry", "imbalance")
                    else 2
                )
                todo.append((prio, r["seed"], out, cache, r))
    todo.sort(key=lambda x: (x[0], x[1]))
    for _, _, out, cache, r in todo:
        run(out, [M.Case(**{k: r[k] for k in FIELDS})], Path(cache))


if __name__ == "__main__":
    main()
