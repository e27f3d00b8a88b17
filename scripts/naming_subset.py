"""Per-cause naming on a seeded open-loop subset of the doctor's matrix (issue 12), one JSON line
per case, resumable: cases already in OUT are skipped, so a batch can be stopped and continued.

    nice -n 5 .venv/bin/python scripts/naming_subset.py OUT.jsonl --causes saturation,delay \
        --sizes 1,3,10,30 --reps 20 --seed 2 [--nulls 30]

Each line: the case (seed, cause, size m, noise units, effect text, profile, σv, plant), what the
doctor named, its standardised statistics (z of every tested cause, threshold), the reason of a
model_mismatch, and the analysis time. Summarise with `--summary`.
"""

from __future__ import annotations

import argparse
import dataclasses
import gzip
import json
import math
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from tvsd.analysis import matrix as M


def _run(case: M.Case, seconds: float, tmp: Path) -> dict[str, object]:
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.sim.record import record

    cfg = M.case_config(load_config(), case)
    effects = (parse_effect(case.effect),) if case.effect else ()
    path = tmp / f"case{case.seed}.csv"
    record(cfg, path, case.profile, seconds, effects, case.seed, rps=case.rps or 20.0)
    t0 = time.perf_counter()
    row: dict[str, object] = {**dataclasses.asdict(case)}
    try:
        dg = diagnose(load(path, cfg), cfg.plant.v0)
        row.update(
            found=dg.cause,
            effect_found={k: v for k, v in dg.effect.items() if isinstance(v, (int, float, str))},
            reason=dg.reason,
            threshold=dg.outcome.threshold,
            z={s.cause: round(float(s.z), 3) for s in dg.ranked},
            colour_p=dg.noise.colour_p,
            peak_q=dg.noise.peak_q,
            peak_lr=dg.noise.peak_lr,
            peak_hz=dg.noise.peak_hz,
            # the residual's Welch spectrum in the band, so a spectral rule can be re-evaluated
            # on these cases without rerunning them
            J=dg.params["J"],
            band_hz=dg.design.prep.band.cutoff_hz,
            rate_rows=1.0 / float(np.median(np.diff(dg.design.prep.t_rows))),
            n_rows=len(dg.design.prep.t_rows),
            psd_f=[round(float(x), 4) for x in dg.noise.freq[dg.noise.freq <= dg.design.prep.band.cutoff_hz]],
            psd=[float(f"{x:.5g}") for x in dg.noise.psd[dg.noise.freq <= dg.design.prep.band.cutoff_hz]],
        )
    except Exception as exc:  # a bad case is a result too
        row["found"] = f"error: {type(exc).__name__}: {exc}"[:160]
    row["seconds"] = time.perf_counter() - t0
    path.unlink(missing_ok=True)
    return row


def _done(out: Path) -> set[tuple[int, str, float]]:
    if not out.exists():
        return set()
    keys = set()
    for line in out.read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            keys.add((r["seed"], r["cause"], r["size"]))
    return keys


def _text(path: Path) -> str:
    return gzip.decompress(path.read_bytes()).decode() if path.suffix == ".gz" else path.read_text()


def summary(paths: list[Path]) -> None:
    rows = [json.loads(x) for p in paths if p.exists() for x in _text(p).splitlines() if x.strip()]
    table: dict[str, dict[float, list[dict[str, object]]]] = defaultdict(lambda: defaultdict(list))
    for r in rows:
        table[r["cause"]][r["size"]].append(r)
    for cause in sorted(table):
        parts = []
        for m in sorted(table[cause]):
            rs = table[cause][m]
            ok = (
                sum(r["found"] == cause for r in rs)
                if cause != "none"
                else sum(r["found"] == "none" for r in rs)
            )
            nu = [float(r["noise_units"]) for r in rs if math.isfinite(float(r["noise_units"]))]
            med = f" ~{sorted(nu)[len(nu) // 2]:.3g}u" if nu else ""
            parts.append(f"{m:g}x {ok}/{len(rs)}{med}")
        wrong: dict[str, int] = defaultdict(int)
        for rs in table[cause].values():
            for r in rs:
                if r["found"] != cause:
                    wrong[str(r["found"])[:40]] += 1
        print(f"{cause:20s} " + ", ".join(parts) + f"   instead: {dict(wrong)}")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path, nargs="+")
    ap.add_argument("--causes", default="")
    ap.add_argument("--sizes", default="1,3,10,30")
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--nulls", type=int, default=0)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--summary", action="store_true")
    a = ap.parse_args()
    if a.summary:
        summary(a.out)
        return 0
    out = a.out[0]
    M.SIZES = tuple(float(s) for s in a.sizes.split(","))
    causes = tuple(c for c in a.causes.split(",") if c) or None
    all_cases = M.cases(
        n_null=a.nulls, reps=a.reps, seed=a.seed, causes=causes or ("imbalance",), seconds=a.seconds
    )
    if not causes:
        all_cases = [c for c in all_cases if c.cause == "none"]
    done = _done(out)
    with tempfile.TemporaryDirectory() as tmp:
        for case in all_cases:
            if (case.seed, case.cause, case.size) in done:
                continue
            row = _run(case, a.seconds, Path(tmp))
            with out.open("a") as f:
                f.write(json.dumps(row, default=float) + "\n")
            print(case.cause, case.size, row["found"], f"{row['seconds']:.1f}s", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
