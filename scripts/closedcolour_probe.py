"""The noise colour's test on closed-loop matrix recordings, two residuals side by side: the
least-squares residual the doctor judged (`ls_*`) and the instrumented fit's y − X·θ_IV on the
measured columns (`iv_*`, closed_checks.plant_noise), with the doctor's answer
(docs/measurements/closedcolour.md).

    python scripts/closedcolour_probe.py OUT.jsonl CACHE --reps 8 --sizes 3,10,30 --seed 71 \
        [--nulls 4] [--worker 0 --workers 1]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from tvsd.analysis.closed_checks import plant_noise
from tvsd.analysis.closed_plan import case_config, plan_cells
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.analysis.matrix_open import heldout_gain_skipped
from tvsd.analysis.prep import Band, prepare


def probe(path: Path, case, cfg) -> dict:  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    data = load(path, cfg)
    dg = diagnose(data, cfg.plant.v0)
    prep = prepare(data, Band())
    plant = plant_noise(prep, data, data.units.axis == "rotary", dg.design, dg.outcome.keep)
    row = {
        "seed": case.seed,
        "cause": case.cause,
        "size": case.size,
        "sigma_v": case.sigma_v,
        "rps": case.rps,
        "ls": dg.cause,
        "ls_lr": round(dg.noise.colour_lr, 3),
        "ls_tau": dg.noise.tau_s,
        "ls_band": dg.noise.colour_band_hz,
    }
    if plant is not None:
        row |= {"iv_lr": round(plant.colour_lr, 3), "iv_tau": plant.tau_s, "iv_band": plant.colour_band_hz}
    ident = plant_noise(
        prep, data, data.units.axis == "rotary", dg.design, dg.outcome.keep, identified_only=True
    )
    if ident is not None:
        row |= {"ivi_lr": round(ident.colour_lr, 3), "ivi_tau": ident.tau_s}
    row["s"] = round(time.perf_counter() - t0, 2)
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("cache", type=Path)
    ap.add_argument("--reps", type=int, default=8)
    ap.add_argument("--sizes", default="3,10,30")
    ap.add_argument("--seed", type=int, default=71)
    ap.add_argument("--nulls", type=int, default=4)
    ap.add_argument("--worker", type=int, default=0)
    ap.add_argument("--workers", type=int, default=1)
    a = ap.parse_args()
    cases = plan_cells(a.reps, tuple(float(x) for x in a.sizes.split(",")), a.seed, a.nulls)
    done = {json.loads(x)["seed"] for x in a.out.read_text().splitlines()} if a.out.exists() else set()
    todo = [c for c in cases if (a.cache / f"case{c.seed}.csv").exists() and c.seed not in done]
    with heldout_gain_skipped():
        for k, case in enumerate(todo):
            if k % a.workers != a.worker:
                continue
            row = probe(a.cache / f"case{case.seed}.csv", case, case_config(case))
            with a.out.open("a") as f:
                f.write(json.dumps(row, default=float) + "\n")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
