"""The baseline's coefficients (accelerations per unit column) as the paper's physical parameters,
and the reduced model the doctor simulates with them."""

from __future__ import annotations

import math

import numpy as np

from tvsd.analysis import design as D
from tvsd.analysis import sense
from tvsd.analysis.simulate import ReducedModel

FRICTION_SPEEDS = 41  # quantiles of the rows' |ω| where the friction map is judged


def physical(
    design: D.Design, theta: np.ndarray, cov: np.ndarray, b_u: float, b_omega: float
) -> tuple[dict[str, float], dict[str, float]]:
    """Accelerations per unit column → the paper's parameters: J from the drive's input gain.

    The input gain is a₀ + a₁: the two columns (u now and one sample later) are nearly collinear,
    so their coefficients are strongly anti-correlated and the sum's standard error is far below
    either one's — it needs the covariance, not the two standard errors."""
    v = dict(zip(design.names, theta, strict=False))
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    s = dict(zip(design.names, se, strict=False))
    a = v["a0"] + v["a1"]
    i0, i1 = design.names.index("a0"), design.names.index("a1")
    se_a = math.sqrt(max(float(cov[i0, i0] + cov[i1, i1] + 2 * cov[i0, i1]), 0.0))
    J = b_u / a if a != 0 else math.nan
    p = {
        "input_gain": a,
        "J": J,
        "damping": -v["c"] * J,  # viscous + back-EMF, effort per unit speed
        "kv": -v["c"] * J - b_omega,  # viscous alone, with the config's back-EMF
        "tau_c": -v["f"] * J,
        "d_stribeck": -v["s"] * J,
        "v0": design.v0,
        "offset": -v.get("b", 0.0) * J,
        "time_constant_s": 1.0 / max(-v["c"], 1e-12),
    }
    err = {
        "damping": abs(s["c"] * J),
        "tau_c": abs(s["f"] * J),
        "J": abs(J) * se_a / abs(a) if a != 0 else math.inf,
        "input_gain": se_a,
    }
    w = np.abs(design.prep.rows(design.prep.speed))[design.rows_mask]
    if len(w) and math.isfinite(J):  # the friction map over the speeds the fit saw (sense.py)
        speeds = np.quantile(w, np.linspace(0.0, 1.0, FRICTION_SPEEDS))
        f_min, f_err, f_speed = sense.friction_map(design.names, theta, cov, J, design.v0, speeds)
        p.update(friction_min=f_min, friction_speed=f_speed)
        err["friction_min"] = f_err
    return p, err


def reduced(p: dict[str, float], b_u: float, extra: dict[str, float] | None = None) -> ReducedModel:
    extra = extra or {}
    return ReducedModel(
        J=p["J"] if p["J"] > 0 else 1e-9,
        kv=max(p["damping"], 0.0),
        tau_c=max(p["tau_c"], 0.0),
        d_stribeck=max(p["d_stribeck"], 0.0),
        v0=p["v0"],
        offset=p["offset"],
        b_u=b_u,
        b_omega=0.0,
        kv_neg_scale=extra.get("kv_neg_scale", 1.0),
        tc_neg_scale=extra.get("tc_neg_scale", 1.0),
    )
