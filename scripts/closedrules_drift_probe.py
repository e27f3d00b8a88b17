"""Closed-loop drifts: how much of the drift the instrumented confirmation can see, against what
the recording shows (docs/measurements/closedrules.md, "The drift's miss").

    nice -n 19 .venv/bin/python scripts/closedrules_drift_probe.py ROWS.jsonl CACHE_DIR SEEDS

For each seed (its stored row gives the case; CACHE_DIR/case{seed}.csv its recording):
- `visible`: the drift's torque beyond the doctor's baseline on the confirmation's rows
  (exposure.confirmation_baseline; closed_judge.seen's measure);
- `instrumented`: the same torque built from the instruments' prediction of the command and the
  speed (û, ω̂: instrument.first_stage), beyond the instrumented design's baseline columns on the
  same rows: the part of the drift the confirmation's block (a function of û, ω̂ and t) can
  carry at all;
- the first stage's R² of u and ω (what the reference and the PRBS explain).
Noise units: torque over J·σv.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from tvsd.analysis import absorber, instrument
from tvsd.analysis import closed_plan as CP
from tvsd.analysis import design as D
from tvsd.analysis import matrix as M
from tvsd.analysis.dataset import load
from tvsd.analysis.exposure import Baseline, _drift_torque
from tvsd.analysis.prep import Band, prepare
from tvsd.causes import parse_effect


def main() -> None:
    rows = {json.loads(x)["seed"]: json.loads(x) for x in Path(sys.argv[1]).read_text().splitlines()}
    cache = Path(sys.argv[2])
    for seed in (int(s) for s in sys.argv[3].split(",")):
        r = rows[seed]
        case = M.Case(**{k.name: r[k.name] for k in dataclasses.fields(M.Case)})
        cfg = CP.case_config(case)
        data = load(cache / f"case{seed}.csv", cfg)
        assert case.effect is not None
        p = parse_effect(case.effect).params
        par, rel = str(p["parameter"]), float(p["relative_change"])
        prep = prepare(data, Band())
        measured = absorber.absorb(D.build(prep, data.offset_term, True))
        iv, fs = instrument.instrumented(prep, data.offset_term, True)
        iv = absorber.absorb(iv)
        rows_iv = iv.rows_mask
        omega = data.speed if data.speed is not None else np.gradient(data.position, data.t)
        jsv = cfg.plant.J * case.sigma_v
        seen = Baseline(measured.X[rows_iv], rows_iv, prep.band_rows)
        visible = seen.beyond(_drift_torque(par, rel, data.u, omega, cfg.plant)) / jsv
        inst = Baseline(iv.X[rows_iv], rows_iv, prep.band_rows)
        instrumented = inst.beyond(_drift_torque(par, rel, fs.u_hat, fs.speed_hat, cfg.plant)) / jsv
        out = {
            "seed": seed,
            "effect": case.effect,
            "sigma_v": case.sigma_v,
            "visible": round(visible, 4),
            "instrumented": round(instrumented, 4),
            "r2_u": round(fs.r2_u, 4),
            "r2_speed": round(fs.r2_speed, 4),
            "ls": r.get("ls"),
        }
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
