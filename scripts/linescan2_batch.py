"""Outsider cases of one sample rate through `tvsctl analyze --json`: nulls or modes, resumable.

    nice -n 19 .venv/bin/python scripts/linescan2_batch.py --seeds 14000:14999 --fs 500 --open \
        [--cause resonance:6 --lo-hz 50 --hi-hz 80] --set /tmp/ls2/set --out OUT.jsonl
    .venv/bin/python scripts/linescan2_batch.py --summary OUT.jsonl [OUT2.jsonl ...]

Each case seed is drawn by tests/outsider_bench.py (`draw(seed, cause, size)`: the plant, sensor,
rate and excitation come from the seed alone, so a null and its mode share them); cases whose
rate is not --fs (or closed loop with --open, or a mode outside --lo-hz..--hi-hz) are skipped
without being written. The recording is kept in --set (a second run, e.g. the code before on
PYTHONPATH, reuses it); one JSON line per case goes to --out: the answer, the resonance
candidate's score and frequency, the mode's true frequency. `--summary` prints the false alarms
(nulls) or the modes named `resonance` within 1 Hz, with 95 % Clopper–Pearson intervals.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import outsider_bench as ob
from outsider_run import cp95

TVSCTL = str(Path(sys.executable).parent / "tvsctl")


def _row(s: ob.Spec, path: Path) -> dict[str, Any]:
    p = subprocess.run([TVSCTL, "analyze", str(path), "--json", "--quiet"], capture_output=True, text=True)
    try:
        r = json.loads(p.stdout)
    except json.JSONDecodeError:
        return {"name": s.name, "cause": f"exit{p.returncode}", "error": (p.stderr or p.stdout).strip()[-200:]}
    res = next((c for c in r.get("candidates", []) if c["cause"] == "resonance"), {})
    return {
        "name": s.name, "fs": s.fs, "seconds": s.seconds, "excitation": s.excitation, "unit": s.unit,
        "omega": s.sensor["omega"], "cpr": s.sensor["cpr"], "truth": s.truth.get("frequency_hz"),
        "size": s.size, "cause": r.get("cause"), "effect": r.get("effect"),
        "res_score": res.get("score"), "res_hz": (res.get("effect") or {}).get("frequency_hz"),
        "floor_hz": (r.get("noise") or {}).get("quantisation_floor_hz"),
    }  # fmt: skip


def run(a: argparse.Namespace) -> int:
    lo, hi = (int(x) for x in a.seeds.split(":"))
    cause, size = (a.cause.split(":")[0], float(a.cause.split(":")[1])) if a.cause else ("none", 0.0)
    done = set()
    if a.out.exists():
        done = {json.loads(line)["name"] for line in a.out.read_text().splitlines() if line.strip()}
    a.set.mkdir(parents=True, exist_ok=True)
    n = 0
    for seed in range(lo, hi + 1):
        if a.limit and n >= a.limit:
            break
        s = ob.draw(seed, cause, size)
        if s.fs != a.fs or (a.open and s.excitation == "closed"):
            continue
        f0 = s.truth.get("frequency_hz")
        if f0 is not None and not a.lo_hz <= f0 <= a.hi_hz:
            continue
        n += 1
        if s.name in done:
            continue
        path = a.set / f"{s.name}-{cause}{size:g}.csv"
        if not path.exists():
            ob.write(path, s, ob.make(s))
        with a.out.open("a") as fh:
            fh.write(json.dumps(_row(s, path)) + "\n")
    return 0


def summary(files: list[Path]) -> int:
    rows = [json.loads(line) for f in files for line in f.read_text().splitlines() if line.strip()]
    refused = [r for r in rows if str(r["cause"]).startswith("exit")]  # one line, exit 2: not a name
    rows = [r for r in rows if r not in refused]
    print(f"refused (no verdict): {len(refused)} {[r['name'] for r in refused]}")
    nulls = [r for r in rows if r.get("truth") is None]
    modes = [r for r in rows if r.get("truth") is not None]
    if nulls:
        bad = [r for r in nulls if r["cause"] != "none"]
        lo, hi = cp95(len(bad), len(nulls))
        print(f"nulls: {len(bad)}/{len(nulls)} named = {100 * len(bad) / len(nulls):.2f} % "
              f"(95 % CP {100 * lo:.2f}–{100 * hi:.2f} %)")  # fmt: skip
        for key in ("omega", "excitation", "unit"):
            for v in sorted({str(r[key]) for r in nulls}):
                sub = [r for r in nulls if str(r[key]) == v]
                print(f"  {key}={v}: {sum(r['cause'] != 'none' for r in sub)}/{len(sub)}")
        for r in bad:
            print(f"  {r['name']}: {r['cause']} {r.get('effect')}")
    if modes:
        hit = [r for r in modes if r["cause"] == "resonance" and abs((r.get("res_hz") or 0) - r["truth"]) <= 1.0]
        lo, hi = cp95(len(hit), len(modes))
        print(f"modes: {len(hit)}/{len(modes)} named at the mode = {100 * len(hit) / len(modes):.1f} % "
              f"(95 % CP {100 * lo:.1f}–{100 * hi:.1f} %)")  # fmt: skip
        other: dict[str, int] = {}
        for r in modes:
            if r not in hit:
                other[str(r["cause"])] = other.get(str(r["cause"]), 0) + 1
        print(f"  otherwise: {other}")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="14000:14999", help="LO:HI, the case seeds drawn")
    ap.add_argument("--fs", type=float, default=500.0)
    ap.add_argument("--open", action="store_true", help="open loop only")
    ap.add_argument("--cause", default=None, help="e.g. resonance:6 (default: nulls)")
    ap.add_argument("--lo-hz", type=float, default=0.0)
    ap.add_argument("--hi-hz", type=float, default=1e9)
    ap.add_argument("--limit", type=int, default=0, help="at most this many cases of the rate")
    ap.add_argument("--set", type=Path, default=Path("/tmp/linescan2/set"))
    ap.add_argument("--out", type=Path)
    ap.add_argument("--summary", type=Path, nargs="+")
    a = ap.parse_args(argv)
    if a.summary:
        return summary(a.summary)
    if a.out is None:
        ap.error("--out is required")
    return run(a)


if __name__ == "__main__":
    raise SystemExit(main())
