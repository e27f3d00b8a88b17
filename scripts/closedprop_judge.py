"""The doctor's answer on a set of recordings, one JSON row per file, and their false-alarm rate
(docs/measurements/closedprop.md). The code judged is whatever `tvsd` imports (a frozen
`git archive` on PYTHONPATH for "before").

    nice -n 19 .venv/bin/python scripts/closedprop_judge.py run OUT.jsonl KIND FILE ...
        KIND: n91 (tvsd's closed nulls /work/wt/nulls91/cache/identify-SEED.csv, each with the
        config the matrix drew for it) or outsider (the default config, as tvsctl analyze)
    .venv/bin/python scripts/closedprop_judge.py summary OUT.jsonl [BEFORE.jsonl]

A refusal (exit 2 in tvsctl: DataFileError) is a row with `refused`; a file whose answer is not
`none` is an alarm (every file judged here is a null). The held-out speed simulation is skipped
(it runs after the answer).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

from closed14_nulls import config  # the matrix's config of a closed null, by its seed

from tvsd.analysis.matrix import clopper_pearson


def judge(path: Path, cfg: Any) -> dict[str, Any]:
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.matrix_open import heldout_gain_skipped
    from tvsd.errors import DataFileError

    t0 = time.perf_counter()
    try:
        with heldout_gain_skipped():
            dg = diagnose(load(path, cfg), cfg.plant.v0)
    except DataFileError as exc:
        return {"found": "refused", "why": str(exc)[:300], "s": round(time.perf_counter() - t0, 1)}
    except Exception as exc:  # a failing file is a result too
        return {"found": f"error: {type(exc).__name__}: {exc}"[:200], "s": round(time.perf_counter() - t0, 1)}
    return {
        "found": dg.cause,
        "threshold": round(float(dg.outcome.threshold), 3),
        "top": [[s.cause, round(float(s.z), 2)] for s in dg.ranked[:3]],
        "s": round(time.perf_counter() - t0, 1),
    }


def run(out: Path, kind: str, files: list[str]) -> None:
    done = {json.loads(x)["name"] for x in out.read_text().splitlines()} if out.exists() else set()
    for name in files:
        path = Path(name)
        if str(path) in done:
            continue
        row = {"name": str(path)} | judge(path, config(kind, path))
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps({"name": path.stem, "found": row["found"]}), flush=True)


def rows(path: str) -> dict[str, dict[str, Any]]:
    lines = Path(path).read_text().splitlines()
    return {Path(r["name"]).stem: r for r in (json.loads(x) for x in lines if x.strip())}


def summary(path: str, before: str | None) -> None:
    now = rows(path)
    judged = [k for k, r in now.items() if not _not_judged(r)]
    alarms = sorted(k for k in judged if now[k]["found"] != "none")
    lo, hi = clopper_pearson(len(alarms), len(judged)) if judged else (float("nan"), float("nan"))
    res: dict[str, Any] = {
        "files": len(now),
        "refused": sorted(k for k, r in now.items() if r["found"] == "refused"),
        "errors": sorted(k for k, r in now.items() if r["found"].startswith("error")),
        "judged": len(judged),
        "alarms": [[k, now[k]["found"]] for k in alarms],
        "rate": f"{len(alarms)}/{len(judged)}",
        "ci95_pct": [round(100 * lo, 2), round(100 * hi, 2)],
    }
    if before is not None:
        old = rows(before)
        moved = [k for k in sorted(now) if k in old and old[k]["found"] != now[k]["found"]]
        res["changed"] = [[k, old[k]["found"], now[k]["found"]] for k in moved]
        res["in_both"] = sum(k in old for k in now)
    print(json.dumps(res, indent=1))


def _not_judged(row: dict[str, Any]) -> bool:
    return bool(row["found"] == "refused" or row["found"].startswith("error"))


if __name__ == "__main__":
    if sys.argv[1] == "run":
        run(Path(sys.argv[2]), sys.argv[3], sys.argv[4:])
    elif sys.argv[1] == "summary":
        summary(sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else None)
    else:
        sys.exit(__doc__)
