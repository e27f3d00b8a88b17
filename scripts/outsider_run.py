"""Generate the outsider bench's seeded set (tests/outsider_bench.py) and run the doctor on it.

    nice -n 5 .venv/bin/python scripts/outsider_run.py run /tmp/outsider/set2 OUT.w0.jsonl \
        --seed 7 --reps 2 --nulls 30 [--worker 0 --workers 2]
    .venv/bin/python scripts/outsider_run.py summary 'OUT*.jsonl' [--markdown]

`run` writes each recording once (kept in the set folder: a rerun reuses it), runs
`tvsctl analyze FILE --json` on it and appends one JSON line (case, answer, wall time) per file;
cases already in OUT are skipped. `summary` tabulates named/n per cause and size, the false
alarms on the nulls with their 95 % Clopper–Pearson interval, and the wall time per file.
"""

from __future__ import annotations

import argparse
import glob
import json
import resource
import subprocess
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import beta

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import outsider_bench as ob

TVSCTL = str(Path(sys.executable).parent / "tvsctl")


def cp95(k: int, n: int) -> tuple[float, float]:
    lo = 0.0 if k == 0 else float(beta.ppf(0.025, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(0.975, k + 1, n - k))
    return lo, hi


def run(a: argparse.Namespace) -> int:
    a.set.mkdir(parents=True, exist_ok=True)
    done = set()
    if a.out.exists():
        done = {json.loads(line)["name"] for line in a.out.read_text().splitlines() if line.strip()}
    only = set(a.names.read_text().split()) if a.names else None
    cases = ob.plan(a.seed, a.reps, a.nulls, tuple(float(m) for m in a.sizes.split(",")))
    order = np.random.default_rng(a.seed).permutation(len(cases))  # a batch cut short is still a mix
    for k, (seed, cause, m) in enumerate(cases[i] for i in order):
        if k % a.workers != a.worker:
            continue
        s = ob.draw(seed, cause, m)
        if s.name in done or (only is not None and s.name not in only):
            continue
        path = a.set / f"{s.name}.csv"
        if not path.exists():
            ob.write(path, s, ob.make(s))
        t0, c0 = time.monotonic(), resource.getrusage(resource.RUSAGE_CHILDREN)
        p = subprocess.run([TVSCTL, "analyze", str(path), "--json"], capture_output=True, text=True)
        wall, c1 = time.monotonic() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)  # the load does not inflate it
        try:
            ans = json.loads(p.stdout)
        except json.JSONDecodeError:
            ans = {"cause": f"exit{p.returncode}", "error": (p.stderr or p.stdout).strip()[-300:]}
        row = {"name": s.name, "spec": ob.truth_of(s), "cause": ans.get("cause"), "effect": ans.get("effect"),
               "causes": [c.get("cause") for c in ans.get("causes", [])],
               "candidates": [(c["cause"], round(c["score"], 2)) for c in ans.get("candidates", [])[:4]],
               "error": ans.get("error"), "wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
               "rc": p.returncode}  # fmt: skip
        with a.out.open("a") as fh:
            fh.write(json.dumps(row) + "\n")
        print(s.name, cause, m, "->", row["cause"], f"{wall:.1f}s", flush=True)
    return 0


def summary(a: argparse.Namespace) -> int:
    rows = [
        json.loads(line)
        for f in sorted(glob.glob(a.pattern))
        for line in Path(f).read_text().splitlines()
        if line.strip()
    ]
    if a.override:  # rows re-run on a changed doctor replace the same cases' rows
        newer = {json.loads(line)["name"]: json.loads(line) for f in sorted(glob.glob(a.override))
                 for line in Path(f).read_text().splitlines() if line.strip()}  # fmt: skip
        rows = [newer.get(r["name"], r) for r in rows]
    per: dict[tuple[str, float], list[bool]] = defaultdict(list)
    wrong: dict[str, Counter[str]] = defaultdict(Counter)
    nulls = [r for r in rows if r["spec"]["cause"] == "none"]
    for r in rows:
        c = r["spec"]["cause"]
        if c == "none":
            continue
        ok = r["cause"] == c
        per[(c, r["spec"]["size"])].append(ok)
        if not ok:
            wrong[c][r["cause"]] += 1
    sizes = sorted({m for _, m in per})
    print("| cause | " + " | ".join(f"{m:g}×" for m in sizes) + " | named instead |")
    print("|---|" + "---|" * (len(sizes) + 1))
    for c in ob.CAUSES:
        cells = [f"{sum(per[(c, m)])}/{len(per[(c, m)])}" for m in sizes]
        inst = ", ".join(f"{k} {v}" for k, v in wrong[c].most_common())
        print(f"| {c} | " + " | ".join(cells) + f" | {inst} |")
    fa = [r for r in nulls if r["cause"] != "none"]
    lo, hi = cp95(len(fa), len(nulls)) if nulls else (0, 1)
    print(f"\nnulls: {len(fa)}/{len(nulls)} false alarms (95 % CI {100 * lo:.1f}–{100 * hi:.1f} %): "
          + ", ".join(f"{k} {v}" for k, v in Counter(r["cause"] for r in fa).most_common()))  # fmt: skip
    by = defaultdict(list)
    for r in rows:
        by[(r["spec"]["excitation"] == "closed")].append(r["cause"] == r["spec"]["cause"])
    for closed, oks in sorted(by.items()):
        print(f"{'closed' if closed else 'open'} loop: {sum(oks)}/{len(oks)} right (nulls included)")
    for key in ("unit", "fs"):
        g2 = defaultdict(list)
        for r in rows:
            g2[r["spec"][key]].append(r["cause"] == r["spec"]["cause"])
        print(f"by {key}: " + ", ".join(f"{k}: {sum(v)}/{len(v)}" for k, v in sorted(g2.items())))
    if a.split:
        split(rows, a.set)
    for key in ("wall_s", "cpu_s"):
        v = sorted(r[key] for r in rows if key in r)
        if v:
            print(f"{key} per file: median {v[len(v) // 2]:.1f} s, max {v[-1]:.1f} s, n={len(v)}")
    return 0


def _sensor(spec: dict[str, Any]) -> str:
    return "encoder diff" if spec["sensor"]["omega"] == "diff" else "tach"


def _loop(spec: dict[str, Any]) -> str:
    return "closed" if spec["excitation"] == "closed" else "open"


def split(rows: list[dict[str, Any]], set_dir: Path | None) -> None:
    """The nulls' false alarms by sensor, unit, rate and loop (each with its 95 % CP interval),
    and the effects per cause and size with the cases the recording cannot show counted apart
    (scripts/outsider_exposure.py; closed loop from the recorded command, so `--set` is needed)."""
    import outsider_exposure as ox

    nulls = [r for r in rows if r["spec"]["cause"] == "none"]
    keys: dict[str, Callable[[dict[str, Any]], Any]] = {
        "sensor": _sensor, "unit": lambda s: s["unit"], "fs": lambda s: f"{s['fs']:g} Hz", "loop": _loop,
    }  # fmt: skip
    print("\n| nulls by | group | false alarms | 95 % CP | named |\n|---|---|---|---|---|")
    for key, f in keys.items():
        groups: dict[Any, list[dict[str, Any]]] = defaultdict(list)
        for r in nulls:
            groups[f(r["spec"])].append(r)
        for g, rs in sorted(groups.items()):
            fa = [r for r in rs if r["cause"] != "none"]
            lo, hi = cp95(len(fa), len(rs))
            named = ", ".join(f"{k} {v}" for k, v in Counter(r["cause"] for r in fa).most_common())
            print(f"| {key} | {g} | {len(fa)}/{len(rs)} | {100 * lo:.1f}–{100 * hi:.1f} % | {named} |")
    cells: dict[tuple[str, float], dict[str, list[bool]]] = defaultdict(lambda: defaultdict(list))
    instead: dict[str, Counter[str]] = defaultdict(Counter)
    for r in rows:
        sp = r["spec"]
        if sp["cause"] == "none":
            continue
        s = ob.draw(sp["seed"], sp["cause"], sp["size"])
        u = None
        if set_dir is not None and (set_dir / f"{s.name}.csv").exists():
            csv = set_dir / f"{s.name}.csv"
            u = np.loadtxt(csv, delimiter=",", skiprows=_header_lines(csv), usecols=1)
        elif sp["excitation"] == "closed" and sp["cause"] in ("saturation", "deadzone"):
            continue  # a closed loop's command is not replayable
        show = ox.showable(s, u)
        cells[(sp["cause"], sp["size"])][show].append(r["cause"] == sp["cause"])
        if r["cause"] != sp["cause"] and show == "yes":
            instead[sp["cause"]][r["cause"]] += 1
    sizes = sorted({m for _, m in cells})
    print("\nnamed / cases the recording can show (+ marginal: < 1 % of samples; not showable: named/n)\n")
    print("| cause | " + " | ".join(f"{m:g}×" for m in sizes) + " | named instead (showable) |")
    print("|---|" + "---|" * (len(sizes) + 1))
    for c in ob.CAUSES:
        out = []
        for m in sizes:
            d = cells[(c, m)]
            txt = f"{sum(d['yes'])}/{len(d['yes'])}"
            if d["marginal"]:
                txt += f" (+marg. {sum(d['marginal'])}/{len(d['marginal'])})"
            if d["no"]:
                txt += f" (not showable {sum(d['no'])}/{len(d['no'])})"
            out.append(txt)
        print(
            f"| {c} | "
            + " | ".join(out)
            + " | "
            + ", ".join(f"{k} {v}" for k, v in instead[c].most_common())
            + " |"
        )


def _header_lines(path: Path) -> int:
    with path.open() as fh:
        return next(i for i, line in enumerate(fh) if not line.startswith("#")) + 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("set", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("--seed", type=int, default=7)
    r.add_argument("--reps", type=int, default=3)
    r.add_argument("--nulls", type=int, default=36)
    r.add_argument("--worker", type=int, default=0)
    r.add_argument("--workers", type=int, default=1)
    r.add_argument("--names", type=Path, default=None, help="a file of case names: run only these")
    r.add_argument("--sizes", default="2,6,20", help="effect sizes, comma-separated (the plan's m)")
    s = sub.add_parser("summary")
    s.add_argument("pattern")
    s.add_argument(
        "--split", action="store_true", help="nulls by sensor/unit/rate/loop; effects by what they show"
    )
    s.add_argument("--override", default=None, help="rows (a glob) that replace the same cases' rows")
    s.add_argument("--set", type=Path, default=None, help="the recordings (the command for the exposure)")
    a = ap.parse_args()
    return run(a) if a.cmd == "run" else summary(a)


if __name__ == "__main__":
    raise SystemExit(main())
