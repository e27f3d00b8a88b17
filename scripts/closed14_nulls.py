"""Closed-loop recordings judged with rules.asym_ls_alone on (`lsap`) and, where it can matter, off
(`lsap0`): does letting a powerless confirmation's friction asymmetry stand on least squares raise
alarms, and what do the split's windows (tvsd.analysis.asymmetry) say on nulls whatever the gate?
docs/measurements/closed14.md.

    nice -n 19 .venv/bin/python scripts/closed14_nulls.py run OUT.jsonl KIND FILE ...
        KIND: n91 / n52 (tvsd's closed nulls /work/wt/nulls91|52/cache/identify-SEED.csv, each with
        the config the matrix drew for it) or outsider (the default config, as tvsctl analyze);
        FILE[=CAUSE]: an effect's true cause after '='
    .venv/bin/python scripts/closed14_nulls.py summary 'OUT*.jsonl'

The flag can change an answer only through a friction asymmetry above the gate (verdict._ls_alone
is asked nowhere else for it), so `lsap0` is run only when its z passed the gate or something
was named; otherwise its answer is the same computation (`off_copied`). The held-out speed
simulation is skipped (it runs after the answer).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import jsonl_rows

from tvsd.analysis.matrix import clopper_pearson


def config(kind: str, path: Path) -> Any:
    from tvsd.analysis import matrix as M
    from tvsd.config import load_config

    if kind == "outsider":
        return load_config()
    seed = int(path.stem.split("-")[1])
    base, index = divmod(seed, 10000)
    case = M.cases(index + 1, 0, base, profiles=M.CLOSED_PROFILES)[index]
    assert case.seed == seed, (case.seed, seed)
    return M.case_config(load_config(), case)


def judge(path: Path, cfg: Any, variant: str, level: bool) -> dict[str, Any]:
    from tvsd.analysis import asymmetry
    from tvsd.analysis.closed_judge import VARIANTS
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.matrix_open import heldout_gain_skipped

    t0 = time.perf_counter()
    try:
        with heldout_gain_skipped():
            dg = diagnose(load(path, cfg), cfg.plant.v0, rules=VARIANTS[variant].rules)
    except Exception as exc:  # a refused or failing file is a result too
        return {"found": f"error: {type(exc).__name__}: {exc}"[:160], "s": time.perf_counter() - t0}
    fa = next((s for s in dg.ranked if s.cause == "friction_asymmetry"), None)
    row: dict[str, Any] = {
        "found": dg.cause,
        "threshold": round(float(dg.outcome.threshold), 3),
        "z_fa": None if fa is None else round(float(fa.z), 3),
        "why_fa": None if fa is None or fa.why_not is None else fa.why_not[0],
        "ratio": None if fa is None else fa.effect.get("ratio"),
        "top": [[s.cause, round(float(s.z), 2)] for s in dg.ranked[:3]],
    }
    t = next((x for x in dg.outcome.tested if x.cause == "friction_asymmetry"), None)
    if level and t is not None and t.option is not None and t.coef is not None:
        lv = asymmetry.split_level(dg.design, dg.outcome, t.option.block, t.coef)
        row["level"] = lv.as_dict()
    row["s"] = round(time.perf_counter() - t0, 1)
    return row


def run(out: Path, kind: str, files: list[str]) -> None:
    done = {json.loads(x)["name"] for x in out.read_text().splitlines()} if out.exists() else set()
    for arg in files:
        name, _, cause = arg.partition("=")
        path = Path(name)
        if str(path) in done:
            continue
        cfg = config(kind, path)
        on = judge(path, cfg, "lsap", level=True)
        z, thr = on.get("z_fa"), on.get("threshold")
        if (z is not None and thr is not None and z > thr) or on["found"] != "none":
            off, copied = judge(path, cfg, "lsap0", level=False), False
        else:
            off, copied = {k: v for k, v in on.items() if k != "level"} | {"s": 0.0}, True
        row = {"name": str(path), "cause": cause or "none", "lsap": on, "lsap0": off, "off_copied": copied}
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps({"name": path.stem, "off": off["found"], "on": on["found"]}), flush=True)


def summary(pattern: str) -> None:
    rows = jsonl_rows.rows(pattern)
    rows = list({r["name"]: r for r in rows}.values())
    nulls = [r for r in rows if r["cause"] == "none"]
    res: dict[str, Any] = {"rows": len(rows), "nulls": len(nulls)}
    for v in ("lsap0", "lsap"):
        ok = [r for r in nulls if not r[v]["found"].startswith("error")]
        alarms = [r for r in ok if r[v]["found"] != "none"]
        lo, hi = clopper_pearson(len(alarms), len(ok)) if ok else (math.nan, math.nan)
        res[v] = {
            "judged": len(ok),
            "false_alarms": len(alarms),
            "ci95_pct": [round(100 * lo, 2), round(100 * hi, 2)],
            "alarms": [[Path(r["name"]).stem, r[v]["found"]] for r in alarms],
        }
    res["changed"] = [
        [Path(r["name"]).stem, r["cause"], r["lsap0"]["found"], r["lsap"]["found"]]
        for r in rows
        if r["lsap0"]["found"] != r["lsap"]["found"]
    ]
    # the nulls where the path was asked: a split above the gate refused for want of power
    res["path_asked"] = [
        [Path(r["name"]).stem, r["lsap0"]["z_fa"], r["lsap0"]["found"], r["lsap"]["found"]]
        for r in nulls
        if r["lsap0"].get("why_fa") == "instrument_no_power"
    ]
    # the split's windows on nulls whatever the gate: how often they alone would let it stand
    lv = [r["lsap"]["level"] for r in nulls if "level" in r["lsap"]]
    res["level_recorded"] = len(lv)
    res["level_stands"] = sum(bool(x["stands"]) for x in lv)
    res["level_enough_windows"] = sum(x["windows"] >= 4 for x in lv)
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    if sys.argv[1] == "run":
        run(Path(sys.argv[2]), sys.argv[3], sys.argv[4:])
    elif sys.argv[1] == "summary":
        summary(sys.argv[2])
    else:
        sys.exit(__doc__)
