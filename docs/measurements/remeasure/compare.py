"""The merged doctor's rows beside the stored ones (branch remeasure): every answer that changed.

.venv/bin/python docs/measurements/remeasure/compare.py outsider   # vs /work/wt/outsider-main/run.w*.jsonl
.venv/bin/python docs/measurements/remeasure/compare.py bench-dev  # vs ../shared/data/bench-dev/truth.json
.venv/bin/python docs/measurements/remeasure/compare.py open       # vs open-matrix/heldout-seed34.w*.jsonl
.venv/bin/python docs/measurements/remeasure/compare.py why FILE... # the rule behind an answer
"""

from __future__ import annotations

import json
import sys
from collections import Counter
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
MAIN_OUTSIDER = Path("/work/wt/outsider-main")
BENCH_DEV = HERE.parents[2] / ".." / "shared" / "data" / "bench-dev"


def rows(files: list[Path]) -> list[dict[str, Any]]:
    return [json.loads(x) for f in files for x in f.read_text().splitlines() if x.strip()]


def outsider() -> None:
    before = {r["name"]: r for r in rows(sorted(MAIN_OUTSIDER.glob("run.w*.jsonl")))}
    after = {r["name"]: r for r in rows(sorted(HERE.glob("outsider.w*.jsonl")))}
    print(f"files: main {len(before)}, merged {len(after)}")
    print("| file | truth | size | unit | fs | ω | main → merged | merged's effect |")
    print("|---|---|---|---|---|---|---|---|")
    changed = 0
    for name in sorted(after):
        a, b = after[name], before[name]
        if a["cause"] == b["cause"]:
            continue
        changed += 1
        s = a["spec"]
        eff = ", ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in (a["effect"] or {}).items())
        print(
            f"| {name} | {s['cause']} | {s['size']:g} | {s['unit']} | {s['fs']:g} | {s['sensor']['omega']} "
            f"| {b['cause']} → **{a['cause']}** | {eff} |"
        )
    print(f"changed: {changed} of {len(after)}")
    good = Counter(
        (after[n]["cause"] == after[n]["spec"]["cause"]) - (before[n]["cause"] == before[n]["spec"]["cause"])
        for n in after
    )
    print(f"right → wrong {good[-1]}, wrong → right {good[1]}, same rightness {good[0]}")


def bench_dev() -> None:
    truth = json.loads((BENCH_DEV / "truth.json").read_text())
    got = {r["name"]: r for r in rows([HERE / "bench-dev.jsonl"])}
    right = fa = nulls = 0
    print("| file | truth | merged | effect |")
    print("|---|---|---|---|")
    for name in sorted(got):
        ans = got[name]["answer"] or {}
        t = truth[name]["name"]
        cause = ans.get("cause", f"exit {got[name]['rc']}")
        right += cause == t
        if t == "none":
            nulls += 1
            fa += cause != "none"
        eff = ", ".join(
            f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in (ans.get("effect") or {}).items()
        )
        print(f"| {name} | {t} | {cause} | {eff} |")
    print(f"named right {right}/{len(got)}; false alarms {fa}/{nulls} nulls")


def open_matrix() -> None:
    src = HERE.parent / "open-matrix"
    before = {r["seed"]: r for r in rows(sorted(src.glob("heldout-seed34.w*.jsonl")))}
    after = {r["seed"]: r for r in rows(sorted(HERE.glob("open-seed34.w*.jsonl")))}
    cells: dict[tuple[str, float], list[int]] = {}
    print("| seed | cause | size | σv | profile | stored → merged | z stored → merged (gate) |")
    print("|---|---|---|---|---|---|---|")
    for seed in sorted(after):
        a, b = after[seed], before[seed]
        c = cells.setdefault((a["cause"], a["size"]), [0, 0, 0])
        c[0] += 1
        c[1] += b["ls"] == b["cause"]
        c[2] += a["ls"] == a["cause"]
        if a["ls"] != b["ls"]:
            k = a["cause"] if a["cause"] != "none" else a["ls"]
            za, zb = a["ls_why"].get("z", {}).get(k), b["ls_why"].get("z", {}).get(k)
            print(
                f"| {seed} | {a['cause']} | {a['size']:g} | {a['sigma_v']} | {a['profile']} "
                f"| {b['ls']} → **{a['ls']}** "
                f"| {k}: {zb} → {za} ({a['ls_why'].get('threshold')}) |"
            )
    print("\n| cell | cases | stored named | merged named |")
    print("|---|---|---|---|")
    for (cause, m), (n, nb, na) in sorted(cells.items()):
        print(f"| {cause} {m:g}× | {n} | {nb}/{n} | {na}/{n} |")


def why(files: list[str]) -> None:
    """Which new code path a file takes (ω re-timed? a quantisation floor?) and each cause's z."""
    import math

    from tvsd.analysis import quantisation
    from tvsd.analysis.dataset import load
    from tvsd.analysis.matrix_closed import analyse
    from tvsd.config import load_config

    cfg = load_config()
    for f in files:
        data = load(Path(f), cfg)
        counts = data.meta.get("encoder_counts_per_rev")
        step = None
        if data.speed is not None:
            step = quantisation.speed_step(data.speed, data.sample_rate_hz, float(counts) if counts else None)
        cause, secs, w = analyse(Path(f), cfg, "ls")
        top = sorted(w.get("z", {}).items(), key=lambda kv: -kv[1] if math.isfinite(kv[1]) else 0)[:4]
        print(
            json.dumps(
                {
                    "file": Path(f).stem,
                    "cause": cause,
                    "timing": data.meta.get("omega_timing"),
                    "speed_step": step,
                    "z": dict(top),
                    "threshold": w.get("threshold"),
                    "reason": w.get("reason"),
                    "why_not": w.get("why_not"),
                    "s": round(secs, 1),
                }
            )
        )


if __name__ == "__main__":
    if sys.argv[1] == "why":
        why(sys.argv[2:])
    else:
        {"outsider": outsider, "bench-dev": bench_dev, "open": open_matrix}[sys.argv[1]]()
