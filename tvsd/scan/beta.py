"""β from pulse timing: the mirror angle at the optical pulse, from the zero pulses around it.

The shaft angle is 2π·n at the zero pulse of revolution n. Between zero pulses the angle is not
uniform in time, so β is read off a quadratic φ(t) through three zero pulses (not a uniform speed
over the previous revolution):
- ``centred``: pulses n−1, n, n+1 of the optical pulse's revolution n — interpolation; the point
  waits for the next zero pulse (≤ one revolution);
- ``causal``: pulses n−2, n−1, n — extrapolation; the point is ready at the optical pulse;
- ``naive`` (baseline, the paper's reading): β = 2π·Δt/T_prev, a line through n−1 and n.
With compensation, the known acceleration's double integral Φ_K (tvsd.scan.compensation) is taken
out of the zero-pulse angles before the fit and put back at the optical pulse, so the quadratic
only has to follow what is left: friction, back-EMF, the unmeasured remainder.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tvsd.scan.compensation import KnownAccel
from tvsd.scan.pulses import CleanPulses

F64 = NDArray[np.float64]
OFFSETS = {"centred": (-1, 0, 1), "causal": (-2, -1, 0), "naive": (-1, 0)}


@dataclass(frozen=True)
class BetaEstimate:
    """One entry per usable optical pulse."""

    t: F64  # s, MCU time of the optical pulse
    beta: F64  # rad
    knots: F64  # (n, k) zero-pulse times used, s
    weights: F64  # (n, k) Lagrange weights of those knots at t
    omega: F64  # rad/s, mean speed over the knots
    compensated: bool
    method: str
    dropped: int  # optical pulses without the zero pulses the method needs (stream ends, gaps)


def lagrange_weights(knots: F64, t: F64) -> F64:
    """Weights w_i with p(t) = Σ w_i·p(knot_i) for every polynomial of degree < k (rows vectorised)."""
    k = knots.shape[1]
    w = np.ones_like(knots)
    for i in range(k):
        for j in range(k):
            if i != j:
                w[:, i] *= (t - knots[:, j]) / (knots[:, i] - knots[:, j])
    return w


def estimate(pulses: CleanPulses, method: str = "centred", known: KnownAccel | None = None) -> BetaEstimate:
    """β for every optical pulse whose revolution has the zero pulses `method` needs."""
    if method not in OFFSETS:
        raise ValueError(f"unknown β method {method!r}; one of {', '.join(OFFSETS)}")
    offs = np.array(OFFSETS[method])
    zt, rev = pulses.zero_t, pulses.zero_rev
    idx = pulses.opt_idx[:, None] + offs[None, :]
    ok = np.all((idx >= 0) & (idx < len(zt)), axis=1)
    idx_c = np.clip(idx, 0, max(len(zt) - 1, 0))
    if len(zt):
        # Consecutive revolution numbers: no missed zero pulse inside the span.
        ok &= np.all(rev[idx_c] - rev[pulses.opt_idx][:, None] == offs[None, :], axis=1)
    t_o = pulses.opt_t[ok]
    knots = zt[idx_c[ok]] if len(zt) else np.zeros((0, len(offs)))
    compensated = known is not None
    if compensated:
        assert known is not None
        cover = known.covers(knots.min(axis=1)) & known.covers(knots.max(axis=1)) & known.covers(t_o)
        t_o, knots = t_o[cover], knots[cover]
    # Times relative to the revolution's own zero pulse keep the polynomial well conditioned.
    t_ref = knots[:, list(offs).index(0)] if len(knots) else np.zeros(0)
    w = lagrange_weights(knots - t_ref[:, None], t_o - t_ref)
    angle = 2.0 * math.pi * offs[None, :].astype(np.float64)  # relative to 2π·n
    beta = (w * angle).sum(axis=1) if len(knots) else np.zeros(0)
    if compensated:
        assert known is not None
        _, phi_knots = known.integrals(knots.ravel())
        _, phi_o = known.integrals(t_o)
        beta = beta - (w * phi_knots.reshape(knots.shape)).sum(axis=1) + phi_o
    span = knots[:, -1] - knots[:, 0] if len(knots) else np.zeros(0)
    omega = 2.0 * math.pi * (len(offs) - 1) / np.where(span > 0, span, np.nan)
    return BetaEstimate(
        t=t_o,
        beta=beta,
        knots=knots,
        weights=w,
        omega=omega,
        compensated=compensated,
        method=method,
        dropped=len(pulses.opt_t) - len(t_o),
    )
