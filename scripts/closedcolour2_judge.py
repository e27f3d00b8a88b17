"""The closed-loop colour rule (`Rules.closed_colour`) on null recordings: one JSON line per file.

    # SIL daemon identify exports, with the quantisation floor of the interpolated angle (after)
    # and without it (before: the frames' timing keys dropped, as integ3's doctor read the file)
    nice -n 19 .venv/bin/python scripts/closedcolour2_judge.py exports OUT.jsonl FILE.csv ...
    # the closed-loop matrix's cached nulls (scripts/doctor_nulls.py --loop closed --cache DIR)
    nice -n 19 .venv/bin/python scripts/closedcolour2_judge.py nulls OUT.jsonl DIR --seed 91 --shard 0/2
    .venv/bin/python scripts/closedcolour2_judge.py summary OUT.jsonl ...

Each row: the cause named with the rule on and off (integ3's default), the colour's likelihood ratio (χ²₁; gate 10.83 at
p = 1e-3), its τ and why it was not named. The held-out speed simulation is skipped (the verdict is
decided before it; scripts/doctor_nulls.py --no-gain). Resumable: files already in OUT are skipped.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

FRAME_KEYS = ("encoder_frame_hz", "encoder_frame_offset_s")


def colour_row(dg: Any) -> dict[str, Any]:
    c = next((s for s in dg.ranked if s.cause == "colored_noise"), None)
    return {
        "cause": dg.cause,
        "causes": [x.cause for x in dg.causes],
        "colour_lr": None if c is None else round(c.z, 3),
        "tau_s": None if c is None else c.effect.get("tau_s"),
        "why_not": None if c is None or c.why_not is None else c.why_not[0],
    }


def judge(data: Any, v0: float, off: bool = True) -> dict[str, Any]:
    """The verdict with the rule on and (`off`) off, as integ3's default was."""
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.rules import DEFAULT

    on = diagnose(data, v0, rules=dataclasses.replace(DEFAULT, closed_colour=True))
    row: dict[str, Any] = {"on": colour_row(on)}
    if off:
        dg = diagnose(data, v0, rules=dataclasses.replace(DEFAULT, closed_colour=False))
        row |= {"off_cause": dg.cause, "off_causes": [x.cause for x in dg.causes]}
    return row


def exports(out: Path, files: list[Path]) -> None:
    from tvsd.analysis.dataset import load
    from tvsd.config import load_config

    cfg = load_config()
    done = _done(out, "file")
    for f in files:
        if str(f) in done:
            continue
        t0 = time.process_time()
        data = load(f, cfg)
        row: dict[str, Any] = {"file": str(f), "frames": {k: data.meta.get(k) for k in FRAME_KEYS}}
        row["after"] = judge(data, cfg.plant.v0)
        bare = dataclasses.replace(data, meta={k: v for k, v in data.meta.items() if k not in FRAME_KEYS})
        row["before"] = judge(bare, cfg.plant.v0)
        row["cpu_s"] = round(time.process_time() - t0, 1)
        _append(out, row)


def nulls(out: Path, cache: Path, seed: int, count: int, shard: str, off: bool) -> None:
    from doctor_nulls import with_speed

    from tvsd.analysis import matrix as M
    from tvsd.analysis.dataset import load
    from tvsd.config import load_config

    base = load_config()
    done = _done(out, "seed")
    i, n = (int(x) for x in shard.split("/"))
    todo = [with_speed(c) for c in M.cases(count, 0, seed, profiles=M.CLOSED_PROFILES)][i::n]
    for case in todo:
        path = cache / f"{case.profile}-{case.seed}.csv"
        if case.seed in done or not path.exists():  # not recorded yet (the lead's batch fills it)
            continue
        cfg = M.case_config(base, case)
        t0 = time.process_time()
        row: dict[str, Any] = {"seed": case.seed, "sigma_v": case.sigma_v, "rps": case.rps}
        row.update(judge(load(path, cfg), cfg.plant.v0, off))
        row["cpu_s"] = round(time.process_time() - t0, 1)
        _append(out, row)


def summary(files: list[Path]) -> None:
    from tvsd.analysis.matrix import clopper_pearson

    rows = [json.loads(x) for f in files for x in f.read_text().splitlines() if x.strip()]
    rows = list({r.get("seed", r.get("file")): r for r in rows}.values())  # a file judged twice: once
    for when in ("after", "before", None):
        picked = [r[when] for r in rows if when in r] if when else [r for r in rows if "on" in r]
        if not picked:
            continue
        n = len(picked)
        on = sum(r["on"]["cause"] != "none" for r in picked)
        off = sum(r.get("off_cause", "none") != "none" for r in picked)
        colour = sum("colored_noise" in r["on"]["causes"] for r in picked)  # first or a later cause
        lrs = sorted(r["on"]["colour_lr"] or 0.0 for r in picked)
        out = {"set": when or "nulls", "n": n}
        for name, k in (("alarms_rule_on", on), ("alarms_rule_off", off), ("colour_named", colour)):
            lo, hi = clopper_pearson(k, n)
            out[name] = f"{k}/{n} = {100 * k / n:.2f} % (95 % CI {100 * lo:.2f}–{100 * hi:.2f} %)"
        named: dict[str, int] = {}
        for r in picked:
            for c in r["on"]["causes"]:
                named[c] = named.get(c, 0) + 1
        out["named_rule_on"] = named
        out["colour_lr_median"] = lrs[n // 2]
        out["colour_lr_max"] = lrs[-1]
        out["above_gate"] = sum(x > 10.83 for x in lrs)
        out["exact_zero"] = sum(x == 0 for x in lrs)
        print(json.dumps(out, ensure_ascii=False))


def _done(out: Path, key: str) -> set[Any]:
    if not out.exists():
        return set()
    return {json.loads(x)[key] for x in out.read_text().splitlines() if x.strip()}


def _append(out: Path, row: dict[str, Any]) -> None:
    with out.open("a") as f:
        f.write(json.dumps(row) + "\n")
    print(json.dumps(row), flush=True)


def main() -> int:
    from doctor_nulls import _no_gain

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("exports", "nulls", "summary"))
    ap.add_argument("out", type=Path)
    ap.add_argument("inputs", type=Path, nargs="*")
    ap.add_argument("--seed", type=int, default=91)
    ap.add_argument("--count", type=int, default=800, help="the null batch's planned nulls (--nulls)")
    ap.add_argument("--shard", default="0/1")
    ap.add_argument(
        "--no-off", action="store_true", help="nulls: the rule on only (the batch's own rows hold the defaults')"
    )
    a = ap.parse_args()
    if a.mode == "summary":
        summary([a.out, *a.inputs])
        return 0
    _no_gain()
    if a.mode == "exports":
        exports(a.out, a.inputs)
    else:
        nulls(a.out, a.inputs[0], a.seed, a.count, a.shard, not a.no_off)
    return 0


if __name__ == "__main__":
    sys.exit(main())
