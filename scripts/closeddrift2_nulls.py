"""Closed-loop nulls (and named cases) judged with rules.drift_ls_alone off (`lsdp0`) and on
(`lsdp`): does letting a powerless confirmation's drift stand on least squares raise alarms?
docs/measurements/closeddrift2.md.

    nice -n 19 .venv/bin/python scripts/closeddrift2_nulls.py nulls91 OUT.jsonl I/N [--max 200]
    nice -n 19 .venv/bin/python scripts/closeddrift2_nulls.py outsider OUT.jsonl DIR I/N o12076[:drift:20] ...
        (o14000c: outsider case 14000 drawn in closed loop whatever its draw said)
    nice -n 19 .venv/bin/python scripts/closeddrift2_nulls.py matrix OUT.jsonl DIR 520144 ...
    nice -n 19 .venv/bin/python scripts/closeddrift2_nulls.py filters OUT.jsonl I/N [--max 200]
    .venv/bin/python scripts/closeddrift2_nulls.py summary 'OUT*.jsonl'

`nulls91`: the lead's recordings /work/wt/nulls91/cache/identify-SEED.csv (read-only; the
closed-loop nulls of `scripts/doctor_nulls.py --loop closed --seed 91`), each with the config the
matrix drew for it. `outsider`: the outsider bench's case drawn again (tests/outsider_bench.py,
written to DIR once), analysed with the default config as `tvsctl analyze` does.

Each file is analysed with the flag on; the flag can change an answer only through a drift
candidate above the gate (verdict._ls_alone is asked nowhere else), so the flag-off analysis is
run only when the drift's z passed the gate or something was named (forward selection's later
steps test again) — otherwise it is the same computation and its answer is copied
(`off_copied`). The held-out speed simulation is skipped (it runs after the answer).
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

NULLS91 = Path("/work/wt/nulls91")


def judge(path: Path, cfg: Any, variant: str) -> dict[str, Any]:
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
    z = {s.cause: round(float(s.z), 3) for s in dg.ranked}
    why = {s.cause: s.why_not[0] for s in dg.ranked if s.why_not}
    drift = next((s for s in dg.ranked if s.cause == "drift"), None)
    return {
        "trend": _trend(dg),
        "found": dg.cause,
        "z_drift": z.get("drift"),
        "threshold": round(float(dg.outcome.threshold), 3),
        "why_drift": why.get("drift"),
        "drift_effect": {k: v for k, v in drift.effect.items() if isinstance(v, (str, float, int))}
        if drift is not None
        else None,
        "s": round(time.perf_counter() - t0, 1),
    }


def _trend(dg: Any) -> dict[str, object] | None:
    """The windows' trend of the decision's drift block (t, φ, step; drift.agrees)."""
    from tvsd.analysis import drift

    t = next((x for x in dg.outcome.tested if x.cause == "drift"), None)
    if t is None or t.option is None or t.coef is None:
        return None
    tr = drift.agrees(dg.design, dg.outcome, str(t.option.effect["parameter"]), float(t.coef[0]))
    return {**tr.as_dict(), "clean_alone": drift.clean_line(tr)}


def both(path: Path, cfg: Any) -> dict[str, Any]:
    on = judge(path, cfg, "lsdp")
    z, thr = on.get("z_drift"), on.get("threshold")
    if (z is not None and thr is not None and z > thr) or on["found"] != "none":
        return {"lsdp": on, "lsdp0": judge(path, cfg, "lsdp0"), "off_copied": False}
    return {"lsdp": on, "lsdp0": {**on, "s": 0.0}, "off_copied": True}


def nulls91(out: Path, shard: str, most: int) -> None:
    from tvsd.analysis import matrix as M
    from tvsd.config import load_config

    w, nw = map(int, shard.split("/"))
    cases = {c.seed: c for c in M.cases(800, 0, 91, profiles=M.CLOSED_PROFILES)}
    lead = {}
    for f in sorted(NULLS91.glob("out/closed91.w*.jsonl")):
        for line in f.read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                lead[r["seed"]] = r["found"]
    files = sorted(NULLS91.glob("cache/identify-*.csv"), key=lambda p: int(p.stem.split("-")[1]))[:most]
    done = {json.loads(x)["seed"] for x in out.read_text().splitlines()} if out.exists() else set()
    for k, path in enumerate(files):
        seed = int(path.stem.split("-")[1])
        if k % nw != w or seed in done or seed not in cases:
            continue
        case = cases[seed]
        cfg = M.case_config(load_config(), case)
        row = {"seed": seed, "cause": case.cause, "lead_found": lead.get(seed), **both(path, cfg)}
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(
            json.dumps(
                {k: row[k] for k in ("seed", "lead_found")} | {v: row[v]["found"] for v in ("lsdp0", "lsdp")}
            ),
            flush=True,
        )


def outsider(out: Path, folder: Path, shard: str, names: list[str]) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    import outsider_bench as ob

    from tvsd.config import load_config

    w, nw = map(int, shard.split("/"))
    folder.mkdir(parents=True, exist_ok=True)
    done = {json.loads(x)["name"] for x in out.read_text().splitlines()} if out.exists() else set()
    for k, name in enumerate(names):
        if k % nw != w or name in done:
            continue
        case, *rest = name.split(":")
        cause, size = (rest[0], float(rest[1])) if rest else ("none", 0.0)
        # a trailing `c`: the draw forced to closed loop (fresh closed-loop nulls: o14000c ...)
        forced = case.endswith("c")
        spec = ob.draw(int(case.lstrip("o").rstrip("c")), cause, size, closed=True if forced else None)
        path = folder / f"{name.replace(':', '-')}.csv"
        if not path.exists():
            ob.write(path, spec, ob.make(spec))
        row = {"name": name, "cause": cause, "excitation": spec.excitation, **both(path, load_config())}
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps({"name": name} | {v: row[v]["found"] for v in ("lsdp0", "lsdp")}), flush=True)


def matrix_nulls(out: Path, folder: Path, seeds: list[str]) -> None:
    """The closed matrix's null SEED·10000 + INDEX (e.g. drift.md's 520144) recorded again as
    tvsd.analysis.matrix draws it (30 s identify), into DIR once."""
    from tvsd.analysis import matrix as M
    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.sim.record import record

    folder.mkdir(parents=True, exist_ok=True)
    for s in seeds:
        base, index = divmod(int(s), 10000)
        case = M.cases(index + 1, 0, base, profiles=M.CLOSED_PROFILES)[index]
        assert case.seed == int(s), (case.seed, s)
        cfg = M.case_config(load_config(), case)
        path = folder / f"{case.profile}-{case.seed}.csv"
        if not path.exists():
            effects = (parse_effect(case.effect),) if case.effect else ()
            record(cfg, path, case.profile, 30.0, effects, case.seed, rps=case.rps or 20.0)
        row = {"seed": case.seed, "cause": case.cause, **both(path, cfg)}
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps(row), flush=True)


def second_filters(out: Path, shard: str, most: int) -> None:
    """How much the LS-alone path's own checks refuse on nulls whatever the gate: per null of
    nulls91, the drift block's z, the windows' trend (t, φ, step), the clean line and the held-out
    gain (the default doctor's design and outcome; the drift block the decision chose)."""
    import numpy as np

    from tvsd.analysis import crossval, drift
    from tvsd.analysis import matrix as M
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.matrix_open import heldout_gain_skipped
    from tvsd.config import load_config

    w, nw = map(int, shard.split("/"))
    cases = {c.seed: c for c in M.cases(800, 0, 91, profiles=M.CLOSED_PROFILES)}
    files = sorted(NULLS91.glob("cache/identify-*.csv"), key=lambda p: int(p.stem.split("-")[1]))[:most]
    done = {json.loads(x)["seed"] for x in out.read_text().splitlines()} if out.exists() else set()
    for k, path in enumerate(files):
        seed = int(path.stem.split("-")[1])
        if k % nw != w or seed in done or seed not in cases:
            continue
        cfg = M.case_config(load_config(), cases[seed])
        try:
            with heldout_gain_skipped():
                dg = diagnose(load(path, cfg), cfg.plant.v0)
        except Exception as exc:
            row: dict[str, Any] = {"seed": seed, "error": str(exc)[:120]}
        else:
            t = next((x for x in dg.outcome.tested if x.cause == "drift"), None)
            row = {"seed": seed, "threshold": round(float(dg.outcome.threshold), 3)}
            if t is not None and t.option is not None and t.coef is not None:
                par = str(t.option.effect["parameter"])
                tr = drift.agrees(dg.design, dg.outcome, par, float(t.coef[0]))
                X_cv = np.column_stack([dg.design.X, t.option.block])
                gain = crossval.heldout_gain(dg.design, dg.outcome, X_cv)
                row |= {"z": round(float(t.z), 3), "parameter": par, **tr.as_dict(),
                        "clean": drift.clean_line(tr), "heldout_gain": round(float(gain), 4)}  # fmt: skip
                row.pop("slope", None)
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")


def summary(pattern: str) -> None:
    rows = jsonl_rows.rows(pattern)
    rows = list({r.get("seed", r.get("name")): r for r in rows}.values())  # a seed judged twice once
    nulls = [r for r in rows if r.get("cause", "none") == "none"]
    effects = [r for r in rows if r.get("cause", "none") != "none"]
    res: dict[str, Any] = {"nulls": len(nulls)}
    for v in ("lsdp0", "lsdp"):
        ok = [r for r in nulls if not r[v]["found"].startswith("error")]
        alarms = [r for r in ok if r[v]["found"] != "none"]
        lo, hi = clopper_pearson(len(alarms), len(ok)) if ok else (math.nan, math.nan)
        res[v] = {
            "judged": len(ok),
            "false_alarms": len(alarms),
            "ci95_pct": [round(100 * lo, 2), round(100 * hi, 2)],
            "alarms": [[r.get("seed", r.get("name")), r[v]["found"]] for r in alarms],
            "drift_alarms": sum(r[v]["found"] == "drift" for r in ok),
        }
    res["changed"] = [
        [r.get("seed", r.get("name")), r["lsdp0"]["found"], r["lsdp"]["found"]]
        for r in rows
        if r["lsdp0"]["found"] != r["lsdp"]["found"]
    ]
    res["drift_above_gate"] = [
        [
            r.get("seed", r.get("name")),
            r["lsdp"]["z_drift"],
            r["lsdp"]["threshold"],
            r["lsdp0"]["why_drift"],
            r["lsdp"]["why_drift"],
        ]
        for r in rows
        if not r["off_copied"]
    ]
    # the nulls where the LS-alone path was asked: a drift above the gate, its windows and folds
    # passed, its confirmation powerless (the flag-off why-not)
    res["path_asked"] = [
        [r.get("seed", r.get("name")), r["lsdp0"]["found"], r["lsdp"]["found"]]
        for r in nulls
        if r["lsdp0"].get("why_drift") == "instrument_no_power"
    ]
    res["lead_disagrees"] = [
        [r["seed"], r["lead_found"], r["lsdp0"]["found"]]
        for r in nulls
        if "lead_found" in r and r["lead_found"] is not None and r["lead_found"] != r["lsdp0"]["found"]
    ]
    if effects:
        res["effects"] = {
            v: f"{sum(r[v]['found'] == r['cause'] for r in effects)}/{len(effects)}"
            for v in ("lsdp0", "lsdp")
        }
    print(json.dumps(res, indent=1))


def main() -> None:
    mode = sys.argv[1]
    if mode == "nulls91":
        most = int(sys.argv[sys.argv.index("--max") + 1]) if "--max" in sys.argv else 10**9
        nulls91(Path(sys.argv[2]), sys.argv[3], most)
    elif mode == "outsider":
        outsider(Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4], sys.argv[5:])
    elif mode == "filters":
        most = int(sys.argv[sys.argv.index("--max") + 1]) if "--max" in sys.argv else 10**9
        second_filters(Path(sys.argv[2]), sys.argv[3], most)
    elif mode == "matrix":
        matrix_nulls(Path(sys.argv[2]), Path(sys.argv[3]), sys.argv[4:])
    elif mode == "summary":
        summary(sys.argv[2])
    else:
        sys.exit(f"unknown mode {mode!r}: nulls91, outsider or summary")


if __name__ == "__main__":
    main()
