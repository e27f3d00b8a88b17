"""False alarms of the model doctor on many null recordings of the randomised matrix, resumable.

Each null of tvsd.analysis.matrix (seeded plant, excitation, σv; no effect) is recorded and
analysed; one JSON line per null goes to --out (what was named, the best candidates' standardised
statistics, the threshold), so an interrupted run resumes where it stopped and the summary
(false alarms, 95 % Clopper–Pearson interval) is computed from the file:

    nice -n 5 .venv/bin/python scripts/doctor_nulls.py --loop open --nulls 300 --seed 21 --out open21.jsonl
    .venv/bin/python scripts/doctor_nulls.py --summary open21.jsonl

(`--shard I/N` splits a run over N processes, each with its own --out; --summary takes them all.)

`--cache DIR` keeps the recordings (and reuses them): the rule can then be re-run on the same
files without simulating them again.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from tvsd.analysis import matrix as M

LOOP_PROFILES = {"open": M.OPEN_PROFILES, "closed": M.CLOSED_PROFILES, "spin": ("spin",)}


def record_case(case: M.Case, seconds: float, path: Path) -> Any:
    """The case's recording (as matrix.run_case makes it) and the config it was made with."""
    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.sim.record import record

    cfg = M.case_config(load_config(), case)
    if not path.exists():
        effects = (parse_effect(case.effect),) if case.effect else ()
        tmp = path.with_suffix(".part")
        record(cfg, tmp, case.profile, seconds, effects, case.seed, rps=case.rps or 20.0)
        tmp.rename(path)
    return cfg


def with_speed(case: M.Case) -> M.Case:
    """`spin` nulls scan at the speed the drawn plant holds (as the matrix's closed family does):
    at 20 rev/s a weak plant's drive sits at its limit, a constant command (refused, exit 2)."""
    if case.profile != "spin" or case.rps:
        return case
    from tvsd.config import load_config

    cfg = load_config()
    plant = dataclasses.replace(cfg.plant, **case.plant)  # type: ignore[arg-type]
    plant = dataclasses.replace(plant, kb=plant.kM * cfg.plant.kb / cfg.plant.kM)
    return dataclasses.replace(case, rps=M.scan_rps(plant, cfg.drive.u_max_v))


def _no_gain() -> None:
    """Skip the held-out speed simulation: it measures the named cause's gain after the cause is
    decided and changes nothing of the verdict, and it is a third of an analysis's CPU."""
    import math as m

    from tvsd.analysis import heldout_sim

    heldout_sim.heldout_speed = lambda *_a, **_k: (m.nan, m.nan, {}, {})  # type: ignore[assignment]


def analyse(case: M.Case, seconds: float, folder: Path) -> dict[str, Any]:
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.errors import DataFileError

    path = folder / f"{case.profile}-{case.seed}.csv"
    cfg = record_case(case, seconds, path)
    t0 = time.process_time()
    row: dict[str, Any] = {
        "seed": case.seed,
        "cause": case.cause,
        "size": case.size,
        "profile": case.profile,
        "sigma_v": case.sigma_v,
        "plant": case.plant,
    }
    try:
        dg = diagnose(load(path, cfg), cfg.plant.v0)
        row["found"] = dg.cause
        row["reason"] = dg.reason
        row["threshold"] = dg.outcome.threshold
        row["top"] = [[t.cause, round(t.z, 3)] for t in dg.outcome.tested[:3]]
        row["z"] = {t.cause: round(t.z, 3) for t in dg.outcome.tested}
        row["ranked"] = [[s.cause, round(s.z, 3), s.significant] for s in dg.ranked[:4]]
        row["causes"] = [[c.cause, round(c.z, 3), c.step] for c in dg.causes]  # every cause named
        row["effect"] = {k: v for k, v in dg.effect.items() if isinstance(v, (int, float, str))}
    except DataFileError as exc:  # refused as bad input (exit 2): no cause named
        row["found"] = "refused"
        row["reason"] = str(exc)[:160]
    except Exception as exc:  # a bad case is a result too
        row["found"] = f"error: {type(exc).__name__}: {exc}"[:160]
    row["cpu_s"] = time.process_time() - t0
    return row


def summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    effects = [r for r in rows if r.get("cause", "none") != "none"]
    rows = [r for r in rows if r.get("cause", "none") == "none"]
    refused = sum(r["found"] == "refused" for r in rows)
    rows = [r for r in rows if r["found"] != "refused"]
    named: dict[str, list[int]] = {}
    for r in effects:
        k = f"{r['cause']}@{r['size']:g}x"
        named.setdefault(k, [0, 0])
        named[k][0] += r["found"] == r["cause"]
        named[k][1] += 1
    n = len(rows)
    alarms = [r for r in rows if r["found"] != "none"]
    lo, hi = M.clopper_pearson(len(alarms), n) if n else (math.nan, math.nan)
    # forward selection (tvsd.analysis.selection): a cause past the first on a null is a false
    # alarm already counted; on an effect case, a cause named besides the hidden one is one too
    later = [r for r in rows + effects if len(r.get("causes", [])) > 1]
    by: dict[str, int] = {}
    for r in alarms:
        by[r["found"].split(":")[0]] = by.get(r["found"].split(":")[0], 0) + 1
    return {
        "nulls": n,
        "refused_as_bad_input": refused,
        "false_alarms": len(alarms),
        "rate_pct": round(100 * len(alarms) / max(n, 1), 2),
        "ci95_pct": [round(100 * lo, 2), round(100 * hi, 2)],
        "named": by,
        "alarm_seeds": [r["seed"] for r in alarms],
        "more_than_one_cause": len(later),
        "more_than_one_cause_seeds": [[r["seed"], [c[0] for c in r["causes"]]] for r in later],
        **({"effects_named": {k: f"{v[0]}/{v[1]}" for k, v in sorted(named.items())}} if named else {}),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--loop", choices=sorted(LOOP_PROFILES), default="open")
    ap.add_argument(
        "--nulls", type=int, help="null recordings (default 50; with --summary: the first N rows only)"
    )
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--cache", type=Path, help="keep (and reuse) the recordings here")
    ap.add_argument("--summary", type=Path, nargs="+", help="only summarise these results files")
    ap.add_argument("--effects", help="effect cases at these matrix sizes (e.g. 3,10) instead of nulls")
    ap.add_argument("--reps", type=int, default=2, help="effect cases per cause and size")
    ap.add_argument("--skip", type=Path, nargs="*", default=[], help="results files whose cases are done")
    ap.add_argument("--shard", default="0/1", help="I/N: this process runs every N-th case from the I-th")
    ap.add_argument("--record-only", action="store_true", help="only make the recordings (--cache)")
    ap.add_argument(
        "--no-gain", action="store_true", help="skip the held-out speed simulation (the verdict is the same)"
    )
    a = ap.parse_args()
    if a.no_gain:
        _no_gain()
    if a.summary:
        rows = [json.loads(x) for f in a.summary for x in f.read_text().splitlines() if x.strip()]
        rows.sort(key=lambda r: r["seed"])
        if a.nulls:
            rows = rows[: a.nulls]
        print(json.dumps(summary(rows)))
        return 0
    if a.out is None:
        ap.error("--out FILE is needed (one JSON line per null; the run resumes from it)")
    done = set()
    for f in [a.out, *a.skip]:
        if f.exists():
            done |= {json.loads(x)["seed"] for x in f.read_text().splitlines() if x.strip()}
    if a.effects:
        sizes = {float(x) for x in a.effects.split(",")}
        todo = [c for c in M.cases(0, a.reps, a.seed, profiles=LOOP_PROFILES[a.loop]) if c.size in sizes]
    else:
        todo = M.cases(a.nulls or 50, 0, a.seed, profiles=LOOP_PROFILES[a.loop])
    i, n_shards = (int(x) for x in a.shard.split("/"))
    todo = [with_speed(c) for c in todo][i::n_shards]
    todo = [c for c in todo if c.seed not in done]
    if a.record_only:
        if a.cache is None:
            ap.error("--record-only needs --cache DIR")
        a.cache.mkdir(parents=True, exist_ok=True)
        for case in todo:
            record_case(case, a.seconds, a.cache / f"{case.profile}-{case.seed}.csv")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        folder = a.cache or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for case in todo:
            row = analyse(case, a.seconds, folder)
            with a.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            if a.cache is None:
                for p in folder.glob("*.csv"):
                    p.unlink()
            print(case.seed, row["found"], f"{row['cpu_s']:.1f}s", file=sys.stderr, flush=True)
    rows = [json.loads(x) for x in a.out.read_text().splitlines() if x.strip()]
    print(json.dumps(summary(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
