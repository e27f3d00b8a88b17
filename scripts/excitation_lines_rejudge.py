"""Re-judge matrix recordings with and without the `# excitation_hz:` line (issue 12, items 3–5).

Each case is a row of a matrix JSON-lines file (its plant, σv, effect) and its recording (a cache
made before the line existed, or recorded here when missing: `tvsctl sim record --profile
identify` with the case's config). The doctor analyses the same samples twice: the line stripped
(as before) and the line set to the case's identify design (config `identify:`, its multisine
lines, tvsd.control.excitation.multisine_lines). One JSON line per case and variant to stdout.

    nice -n 5 .venv/bin/python scripts/excitation_lines_rejudge.py ROWS.jsonl SEED[,SEED...] \
        --recordings DIR [--pattern 'identify-{seed}.csv'] [--seconds 30]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

from tvsd.analysis import matrix as M
from tvsd.analysis.matrix_open import _no_gain
from tvsd.config import load_config
from tvsd.control.excitation import multisine_lines
from tvsd.recording.csvfile import format_lines


def variant(src: Path, dst: Path, lines: str | None) -> None:
    text = src.read_text().splitlines(keepends=True)
    body = [ln for ln in text if not ln.startswith("# excitation_hz:")]
    if lines is not None:
        body.insert(2, f"# excitation_hz: {lines}\n")
    dst.write_text("".join(body))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rows", type=Path)
    ap.add_argument("seeds")
    ap.add_argument("--recordings", type=Path, required=True)
    ap.add_argument("--pattern", default="case{seed}.csv")
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args()
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.causes import parse_effect
    from tvsd.sim.record import record

    _no_gain()
    want = [int(s) for s in args.seeds.split(",")]
    rows = {r["seed"]: r for r in map(json.loads, args.rows.read_text().splitlines())}
    fields = {f.name for f in dataclasses.fields(M.Case)}
    for seed in want:
        r = dict(rows[seed])
        r["effect"] = (
            r.get("effect") if isinstance(r.get("effect"), str) else None
        )  # nulls' rows: the found one
        case = M.Case(
            **{k: v for k, v in r.items() if k in fields} | {"noise_units": r.get("noise_units", 0.0)}
        )
        cfg = M.case_config(load_config(), case)
        src = args.recordings / args.pattern.format(seed=seed)
        if not src.exists():
            effects = (parse_effect(case.effect),) if case.effect else ()
            record(cfg, src, "identify", args.seconds, effects, seed, rps=case.rps or 20.0)
        ident = cfg.identify
        lines = format_lines(multisine_lines(ident.multisine_min_hz, ident.multisine_max_hz))
        for name, declared in (("stripped", None), ("declared", lines)):
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / src.name
                variant(src, path, declared)
                t0 = time.perf_counter()
                dg = diagnose(load(path, cfg), cfg.plant.v0)
                out = {
                    "seed": seed, "cause": case.cause, "size": case.size, "effect": case.effect,
                    "sigma_v": case.sigma_v, "variant": name, "found": dg.cause,
                    "frequency_hz": dg.effect.get("frequency_hz") if dg.cause == "resonance" else None,
                    "z_resonance": next((round(t.z, 3) for t in dg.outcome.tested if t.cause == "resonance"), None),
                    "threshold": round(dg.outcome.threshold, 3), "wall_s": round(time.perf_counter() - t0, 1),
                }  # fmt: skip
                print(json.dumps(out), flush=True)


if __name__ == "__main__":
    sys.exit(main())
