"""Closed-loop colour judged on any moving reference (rules.closed_colour_u_exc off, the rule
before closedcolour2's narrowing) on files without identify's excitation: the outsider bench's
closed loops and the SIL scans. docs/measurements/closedcolour3.md.

    nice -n 19 .venv/bin/python scripts/closedcolour3_judge.py files OUT.jsonl I/N FILE.csv ...
    nice -n 19 .venv/bin/python scripts/closedcolour3_judge.py outsider OUT.jsonl DIR I/N o16000c:colored_noise:6 ...
    .venv/bin/python scripts/closedcolour3_judge.py summary 'OUT*.jsonl'

Each file is analysed as `tvsctl analyze` does (default config), once, with the wide rule. The
default's answer follows from it exactly: the two differ only where the colour is judged by the
wide rule and not by the default (no u_exc) — there the default's `colored_noise` is `none`.
The held-out speed simulation is skipped (it runs after the answer).
"""

from __future__ import annotations

import glob
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.analysis.matrix import clopper_pearson


def reference_shape(data: Any) -> dict[str, float]:
    """The reference after the first fifth: relative spread, level changes (|Δ| > 1 % of the
    level between samples) and the share of the samples that sit on a ramp."""
    ref = data.refs.get("omega_ref")
    if ref is None:
        return {}
    r = np.asarray(ref[len(ref) // 5 :], dtype=float)
    level = float(np.mean(np.abs(r))) or 1.0
    d = np.abs(np.diff(r))
    return {
        "rel_std": round(float(np.std(r)) / level, 4),
        "jumps": int(np.count_nonzero(d > 0.01 * level)),
        "ramp_share": round(float(np.mean((d > 1e-9 * level) & (d <= 0.01 * level))), 4),
    }


def judge(path: Path) -> dict[str, Any]:
    from tvsd.analysis import instrument
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import COLOUR_P, _identify_excited, diagnose
    from tvsd.analysis.matrix_open import heldout_gain_skipped
    from tvsd.analysis.rules import Rules
    from tvsd.config import load_config

    t0 = time.perf_counter()
    cfg = load_config()
    try:
        data = load(path, cfg)
        with heldout_gain_skipped():
            dg = diagnose(data, cfg.plant.v0, rules=Rules(closed_colour_u_exc=False))
    except Exception as exc:  # a refused or failing file is a result too
        return {"found": f"error: {type(exc).__name__}: {exc}"[:160], "s": time.perf_counter() - t0}
    colour = next(s for s in dg.ranked if s.cause == "colored_noise")
    u_exc = _identify_excited(data)
    wide = dg.cause
    default = "none" if (wide == "colored_noise" and not u_exc) else wide
    return {
        "found": default,
        "found_wide": wide,
        "colour_lr": round(float(colour.z), 3),
        "colour_p": float(colour.p),
        "colour_sig_p": bool(colour.p < COLOUR_P),
        "tau_s": colour.effect.get("tau_s"),
        "why_colour": colour.why_not[0] if colour.why_not else None,
        "u_exc": u_exc,
        "moves": instrument.reference_moves(data),
        "ref": reference_shape(data),
        "s": round(time.perf_counter() - t0, 1),
    }


def files(out: Path, shard: str, paths: list[str]) -> None:
    w, nw = map(int, shard.split("/"))
    done = {json.loads(x)["name"] for x in out.read_text().splitlines()} if out.exists() else set()
    for k, p in enumerate(sorted(paths)):
        name = Path(p).name.split(".")[0]
        if k % nw != w or name in done:
            continue
        row = {"name": name, "cause": _cause_of(name), **judge(Path(p))}
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        print(json.dumps({k: row.get(k) for k in ("name", "found", "found_wide", "colour_lr")}), flush=True)


def _cause_of(name: str) -> str:
    """o14000c-colored_noise-6 → colored_noise; a bare outsider name is a null; else unknown."""
    parts = name.split("-")
    if name.startswith("o") and len(parts) == 3:
        return parts[1]
    return "none" if name.startswith("o") else "?"


def outsider(out: Path, folder: Path, shard: str, names: list[str]) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
    import outsider_bench as ob

    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    w, nw = map(int, shard.split("/"))
    for k, name in enumerate(names):
        if k % nw != w:
            continue
        case, *rest = name.split(":")
        cause, size = (rest[0], float(rest[1])) if rest else ("none", 0.0)
        forced = case.endswith("c")  # a trailing `c`: the draw forced to closed loop
        path = folder / f"{name.replace(':', '-')}.csv"
        if not path.exists():
            spec = ob.draw(int(case.lstrip("o").rstrip("c")), cause, size, closed=True if forced else None)
            ob.write(path, spec, ob.make(spec))
        paths.append(str(path))
    files(out, "0/1", paths)



def summary(pattern: str) -> None:
    rows = [json.loads(x) for f in sorted(glob.glob(pattern)) for x in Path(f).read_text().splitlines() if x.strip()]
    rows = list({r["name"]: r for r in rows}.values())
    ok = [r for r in rows if not r["found"].startswith("error")]
    res: dict[str, Any] = {"files": len(rows), "errors": len(rows) - len(ok)}
    for group, sel in (("nulls", [r for r in ok if r["cause"] == "none"]), ("effects", [r for r in ok if r["cause"] != "none"])):
        g: dict[str, Any] = {"n": len(sel)}
        for v in ("found", "found_wide"):
            hit = [r for r in sel if r[v] != "none"] if group == "nulls" else [r for r in sel if r[v] == r["cause"]]
            lo, hi = clopper_pearson(len(hit), len(sel)) if sel else (math.nan, math.nan)
            g[v] = {"k": len(hit), "ci95_pct": [round(100 * lo, 2), round(100 * hi, 2)],
                    "answers": sorted({r[v] for r in sel})}  # fmt: skip
        g["colour_above_gate"] = sorted(
            [[r["name"], r["colour_lr"], r["found_wide"], r["moves"]] for r in sel if r["colour_sig_p"]]
        )
        g["named_wide"] = [[r["name"], r["found_wide"], r["colour_lr"]] for r in sel if r["found_wide"] != r["found"]]
        res[group] = g
    print(json.dumps(res, indent=1))


def main() -> None:
    a = sys.argv[1:]
    if a[0] == "files":
        files(Path(a[1]), a[2], a[3:])
    elif a[0] == "outsider":
        outsider(Path(a[1]), Path(a[2]), a[3], a[4:])
    elif a[0] == "summary":
        summary(a[1])
    else:
        sys.exit("usage: closedcolour3_judge.py files|outsider|summary ...")


if __name__ == "__main__":
    main()
