"""Why the control function (u − û as a regressor) does or does not confirm a closed-loop drift:
per cached matrix recording, the drift's z on the least-squares design, on the same design with
the control function (`control_function` below; in tvsd.analysis.instrument at commit 3e8a4e5,
removed: not adopted), the gate of each, and the share of the drift's best block (orthogonal to
the baseline) that the control function column explains on the rows (R²).
docs/measurements/closedfix.md, "Drift: a control function".

    nice -n 19 .venv/bin/python scripts/closedfix_cf_probe.py ROWS.jsonl CACHE_DIR [SEEDS]
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from tvsd.analysis import absorber, instrument
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis import matrix as M
from tvsd.analysis import closed_plan as CP
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, Prepared, prepare


def control_function(prep: Prepared) -> np.ndarray:
    """The first stage's residual u − û as regression rows (band-filtered, decimated like the
    command column): û is u's projection on the instruments (the reference at every lag and
    identify's PRBS: first_stage's linear prediction, before the clip to the recorded range).
    Added to the least-squares design as a regressor it carries the part of the command that
    answers the noise, so the other coefficients are those of the structural equation (the
    control-function form of 2SLS: Hausman 1978; Rivers & Vuong 1988), while the command
    columns keep their measured variation (the instrumented design replaces them by û's)."""
    fs = instrument.first_stage(prep)
    lin = fs.u_lin if fs.u_lin is not None else fs.u_hat
    return prep.band_rows(prep.data.u - lin)


def share_explained(block: np.ndarray, cf: np.ndarray, X: np.ndarray) -> float:
    """R² of the block's part orthogonal to X on the control function's part orthogonal to X."""
    Q, _ = np.linalg.qr(X)
    b = block - Q @ (Q.T @ block)
    c = cf - Q @ (Q.T @ cf)
    return float((b @ c) ** 2 / max(float(b @ b) * float(c @ c), 1e-300))


def main() -> None:
    rows, cache = Path(sys.argv[1]), Path(sys.argv[2])
    seeds = {int(s) for s in sys.argv[3].split(",")} if len(sys.argv) > 3 else None
    for line in rows.read_text().splitlines():
        r = json.loads(line)
        if seeds is not None and r["seed"] not in seeds:
            continue
        case = M.Case(**{k.name: r[k.name] for k in dataclasses.fields(M.Case)})
        data = load(cache / f"case{case.seed}.csv", CP.case_config(case))
        prep = prepare(data, Band())
        measured = absorber.absorb(D.build(prep, data.offset_term, True))
        cf = control_function(prep)
        with_cf = dataclasses.replace(measured, X=np.column_stack([measured.X, cf]))
        ls, wcf = C.test_all(measured, seed=0), C.test_all(with_cf, seed=0)
        z = {t.cause: t for t in ls.tested}
        best = z["drift"].option if "drift" in z else None
        m = measured.rows_mask
        r2 = share_explained(best.block[m, 0], cf[m], measured.X[m]) if best is not None else float("nan")
        out = {
            "seed": case.seed,
            "effect": case.effect,
            "visible": (r.get("seen") or {}).get("visible"),
            "z_ls": round(next(t.z for t in ls.tested if t.cause == "drift"), 3),
            "gate_ls": round(ls.threshold, 3),
            "z_cf": round(next(t.z for t in wcf.tested if t.cause == "drift"), 3),
            "gate_cf": round(wcf.threshold, 3),
            "drift_option": best.effect if best is not None else None,
            "cf_r2_of_drift_block": round(r2, 3),
        }
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
