"""Largest Lyapunov exponent of the fitted model along the recorded run (MODEL-NOTES §4).

The model's state is (φ, ω) (the current is quasi-static); a tangent vector v is carried along
the simulated trajectory with the Jacobian [[0, 1], [∂ω̇/∂φ, ∂ω̇/∂ω]] and renormalised every step
(Benettin's method with one vector). ∂ω̇/∂ω = −(kv + b_ω)/J plus the slope of the friction map;
∂ω̇/∂φ comes from angle-locked torques (imbalance, cogging). Chaos needs λ1 > 0.
For a spinning shaft the angle direction is neutral (a shifted shaft stays shifted: λ1 ≈ 0), and
speed perturbations decay at λ_speed ≈ −(kv + b_ω)/J: trajectories under the same disturbance
converge, so irregular speed comes from the disturbance, not from the dynamics.
"""

from __future__ import annotations

import math

import numpy as np

from tvsd.analysis.simulate import ReducedModel
from tvsd.model import effects as E


def exponents(
    model: ReducedModel, t: np.ndarray, speed: np.ndarray, phi: np.ndarray, effect: np.ndarray
) -> tuple[float, float]:
    """(λ1, λ_speed) in 1/s along the given (φ, ω) trajectory."""
    v = np.array([1.0, 1.0]) / math.sqrt(2.0)
    total = 0.0
    speed_total = 0.0
    damping = (model.kv + model.b_omega) / model.J
    for k in range(len(t) - 1):
        h = t[k + 1] - t[k]
        w = speed[k]
        slope = 0.0
        if model.d_stribeck > 0 and w != 0:  # d/dω of Δs·exp(−(ω/v0)²)·sgn ω
            slope = (
                -2.0
                * w
                / model.v0**2
                * model.d_stribeck
                * math.exp(-((w / model.v0) ** 2))
                * math.copysign(1, w)
            )
        dwdw = -damping - slope / model.J
        speed_total += dwdw * h
        dwdphi = 0.0
        if effect[E.E_IMB_AMP] != 0:
            dwdphi += effect[E.E_IMB_AMP] * math.cos(phi[k] + effect[E.E_IMB_PHASE]) / model.J
        if effect[E.E_COG_AMP] != 0:
            n = effect[E.E_COG_ORDER]
            dwdphi += effect[E.E_COG_AMP] * n * math.cos(n * phi[k] + effect[E.E_COG_PHASE]) / model.J
        v = np.array([v[0] + h * v[1], v[1] + h * (dwdphi * v[0] + dwdw * v[1])])
        norm = float(np.hypot(v[0], v[1]))
        total += math.log(norm)
        v /= norm
    duration = float(t[-1] - t[0])
    return total / duration, speed_total / duration
