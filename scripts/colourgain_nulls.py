"""colourgain: tvsd's stored null recordings judged by the doctor, what it names and the colour p
(docs/measurements/colourgain.md). Run once per code (the code before by `git archive` on
PYTHONPATH, from a folder with no tvsd in it).

    nice -n 19 .venv/bin/python scripts/colourgain_nulls.py closed91 OUT.jsonl I/N [--max 200]
        (/work/wt/nulls91/cache/identify-SEED.csv, closed loop, each with the matrix's config)
    nice -n 19 .venv/bin/python scripts/colourgain_nulls.py open97 OUT.jsonl I/N [--max 200]
        (/tmp/fn/cache97/*.csv: doctor_nulls.py --loop open --seed 97's recordings)
    .venv/bin/python scripts/colourgain_nulls.py summary 'OUT*.jsonl'
    .venv/bin/python scripts/colourgain_nulls.py compare 'BEFORE*.jsonl' 'AFTER*.jsonl'
        (outsider_run.py's rows: the cases judged in both, every answer that changed)
"""

from __future__ import annotations

import glob
import json
import sys
import time
from pathlib import Path
from typing import Any

import jsonl_rows

from tvsd.analysis.matrix import clopper_pearson

SOURCES = {
    "closed91": (Path("/work/wt/nulls91/cache"), 91, "closed"),
    "open97": (Path("/tmp/fn/cache97"), 97, "open"),
}


def judge(path: Path, cfg: Any) -> dict[str, Any]:
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.matrix_open import heldout_gain_skipped

    t0 = time.perf_counter()
    try:
        with heldout_gain_skipped():
            dg = diagnose(load(path, cfg), cfg.plant.v0)
    except Exception as exc:  # a refused file is a result too
        return {"found": f"error: {type(exc).__name__}: {exc}"[:160], "s": round(time.perf_counter() - t0, 1)}
    n = dg.noise
    return {
        "found": dg.cause,
        "colour_p": n.colour_p,
        "band": n.colour_band_hz,
        "s": round(time.perf_counter() - t0, 1),
    }


def run(kind: str, out: Path, shard: str, most: int) -> None:
    from tvsd.analysis import matrix as M
    from tvsd.config import load_config

    folder, seed, loop = SOURCES[kind]
    w, nw = map(int, shard.split("/"))
    profiles = M.CLOSED_PROFILES if loop == "closed" else M.OPEN_PROFILES
    files = sorted(folder.glob("*.csv"), key=lambda p: int(p.stem.split("-")[-1]))[:most]
    cases = {c.seed: c for c in M.cases(max(800, len(files)), 0, seed, profiles=profiles)}
    done = {json.loads(x)["seed"] for x in out.read_text().splitlines()} if out.exists() else set()
    for k, path in enumerate(files):
        s = int(path.stem.split("-")[-1])
        if k % nw != w or s in done or s not in cases:
            continue
        row = {"seed": s, "file": path.name, **judge(path, M.case_config(load_config(), cases[s]))}
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")


def summary(pattern: str) -> None:
    rows = jsonl_rows.rows(pattern)
    judged = [r for r in rows if not r["found"].startswith("error")]
    named = [r for r in judged if r["found"] != "none"]
    colour = [r for r in judged if r["found"] == "colored_noise"]
    for label, k in (("named anything", len(named)), ("named colored_noise", len(colour))):
        lo, hi = clopper_pearson(k, len(judged))
        print(f"{label}: {k}/{len(judged)} ({100 * lo:.2f}–{100 * hi:.2f} %)")
    ps = [r["colour_p"] for r in judged]
    print(f"refused {len(rows) - len(judged)}; colour p < 0.05: {sum(p < 0.05 for p in ps)}, < 0.01: "
          f"{sum(p < 0.01 for p in ps)}, < 1e-3: {sum(p < 1e-3 for p in ps)}")  # fmt: skip
    for r in named:
        print(f"  {r['file']}: {r['found']} (colour p {r['colour_p']:.3g})")


def compare(before: str, after: str) -> None:
    def rows(pattern: str) -> dict[str, dict[str, Any]]:
        out = {}
        for f in sorted(glob.glob(pattern)):
            for x in Path(f).read_text().splitlines():
                if x.strip():
                    r = json.loads(x)
                    out[r["name"]] = r
        return out

    b, a = rows(before), rows(after)
    both = sorted(set(a) & set(b))
    changed = [n for n in both if a[n]["cause"] != b[n]["cause"]]
    print(f"judged by both: {len(both)}; answers changed: {len(changed)}")
    for n in changed:
        truth = a[n]["spec"]["cause"], a[n]["spec"]["size"]
        print(f"  {n} (truth {truth[0]} {truth[1]:g}x): {b[n]['cause']} -> {a[n]['cause']}")


def main() -> None:
    if sys.argv[1] == "compare":
        compare(sys.argv[2], sys.argv[3])
        return
    if sys.argv[1] == "summary":
        summary(sys.argv[2])
        return
    most = int(sys.argv[sys.argv.index("--max") + 1]) if "--max" in sys.argv else 200
    run(sys.argv[1], Path(sys.argv[2]), sys.argv[3], most)


if __name__ == "__main__":
    main()
