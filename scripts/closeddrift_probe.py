"""Closed-loop drift refused as `not_instrumented`: what the instrumented confirmation can see
(docs/measurements/closeddrift.md).

    nice -n 19 .venv/bin/python scripts/closeddrift_probe.py FILE.csv [FILE.csv ...]

Per file (one JSON line): the drift's z and gate by least squares on every row and on the
confirmation's rows only (instrument.steady_start), and on the instrumented design as
closed_checks.instrumented_check builds it; the drift block's coefficient and standard error by
least squares and on the instrumented design (the LS coefficient in IV standard errors is what
the confirmation could show of the drift least squares found); the first stage's R² and the
structural residual's rms against the least-squares one (θ_IV from instrument.iv_theta).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from tvsd.analysis import absorber, instrument
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis.dataset import load
from tvsd.analysis.gls import gls
from tvsd.analysis.prep import Band, prepare
from tvsd.config import load_config


def _drift(out: C.Outcome) -> Any:
    return next(t for t in out.tested if t.cause == "drift")


def _block(design: D.Design, out: C.Outcome, k: int) -> tuple[float, float]:
    fit = gls(design.y, np.column_stack([design.X, design.options["drift"][k].block]), out.ar, out.keep)
    return float(fit.theta[-1]), float(np.sqrt(fit.cov[-1, -1]))


def probe(path: Path) -> dict[str, Any]:
    data = load(path, load_config())
    prep = prepare(data, Band())
    back_emf = data.b_omega > 0 or data.u_unit == "V"
    meas = absorber.absorb(D.build(prep, data.offset_term, True))
    meas.back_emf = back_emf
    out = C.test_all(meas, seed=0)
    ls = _drift(out)
    par = str(ls.option.effect["parameter"])
    k = [str(o.effect["parameter"]) for o in meas.options["drift"]].index(par)
    t0 = float(data.t[instrument.steady_start(data)])
    late = absorber.absorb(D.build(prep, data.offset_term, True, fit_mask=prep.t_rows >= t0))
    late.back_emf = back_emf
    out_late = C.test_all(late, seed=0)
    iv, fs = instrument.instrumented(prep, data.offset_term, True)
    iv = absorber.absorb(iv)
    iv.back_emf = back_emf
    iv.y = instrument.structural_left_side(iv, meas)
    out_iv = C.test_all(iv, seed=0)
    m = iv.rows_mask
    theta_iv = instrument.iv_theta(iv, meas)
    theta_ls, *_ = np.linalg.lstsq(meas.X[m], meas.y[m], rcond=None)
    c_ls, se_ls = _block(meas, out, k)
    c_iv, se_iv = _block(iv, out_iv, k)
    return {
        "file": str(path),
        "parameter": par,
        "ls_z_gate": [round(float(ls.z), 2), round(float(out.threshold), 2)],
        "confirmation_start_s": round(t0, 2),
        "seconds": round(float(data.t[-1]), 2),
        "ls_z_gate_late_rows": [round(float(_drift(out_late).z), 2), round(float(out_late.threshold), 2)],
        "iv_z_gate": [round(float(_drift(out_iv).z), 2), round(float(out_iv.threshold), 2)],
        "iv_parameter": str(_drift(out_iv).option.effect["parameter"]),
        "ls_coef_se": [c_ls, se_ls],
        "iv_coef_se": [c_iv, se_iv],
        "ls_coef_in_iv_se": round(c_ls / se_iv, 2),
        "r2_u_speed": [round(fs.r2_u, 3), round(fs.r2_speed, 3)],
        "gain_ls_iv": [
            round(float(theta_ls[0] + theta_ls[1]), 2),
            round(float(theta_iv[0] + theta_iv[1]), 2),
        ],
        "resid_rms_iv_over_ls": round(
            float(np.std((meas.y - meas.X @ theta_iv)[m]) / np.std((meas.y - meas.X @ theta_ls)[m])), 2
        ),
    }


def main() -> None:
    with threadpool_limits(limits=1, user_api="blas"):
        for f in sys.argv[1:]:
            print(json.dumps(probe(Path(f))), flush=True)


if __name__ == "__main__":
    main()
