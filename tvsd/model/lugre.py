"""LuGre friction in its standard form (MODEL-NOTES §2), with the bristle state stepped exactly.

    ż = ω − σ0·|ω|·z / g(ω),   τf = σ0·z + σ1·ż + σ2·ω,   g(ω) = τc + (τs − τc)·exp(−(ω/v0)²)

The paper's eq. (15) drops σ1·ω and never gives ż; see MODEL-NOTES §2 for why the standard form is
used. The z equation is stiff (σ0|ω|/g ~ 1e5 1/s at scanning speed), so z is advanced with the exact
solution for ω frozen over the step, and the friction torque returned is its exact mean over the
step: explicit RK4 at 10 kHz would diverge.
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True, fastmath=False)
def stribeck(omega: float, tau_c: float, tau_s: float, v0: float) -> float:
    """g(ω) of eq. (16), in torque units."""
    r = omega / v0
    if r * r > 40.0:  # exp(−40) < 1e-17: the Stribeck bump is gone; skip the exp at speed
        return tau_c
    return tau_c + (tau_s - tau_c) * math.exp(-r * r)


@njit(cache=True, nogil=True)
def lugre_step(
    z0: float,
    omega: float,
    h: float,
    tau_c: float,
    tau_s: float,
    v0: float,
    sigma0: float,
    sigma1: float,
    level: float,
) -> tuple[float, float]:
    """Advance z by h with ω frozen; return (z1, mean of σ0·z + σ1·ż over the step).

    `level` scales g (friction_asymmetry multiplies it for ω < 0). σ2·ω is left to the caller,
    which integrates it with the other viscous terms.
    """
    g = level * stribeck(omega, tau_c, tau_s, v0)
    rate = sigma0 * abs(omega) / g
    x = rate * h
    if x > 1e-9:
        z_ss = omega / rate
        decay = math.exp(-x)
        z1 = z_ss + (z0 - z_ss) * decay
        z_mean = z_ss + (z0 - z_ss) * (1.0 - decay) / x
    else:  # ω ≈ 0: ż = ω to first order
        z1 = z0 + omega * h
        z_mean = z0 + 0.5 * omega * h
    return z1, sigma0 * z_mean + sigma1 * (z1 - z0) / h


def steady_friction(omega: float, tau_c: float, tau_s: float, v0: float, sigma2: float) -> float:
    """Steady-state LuGre friction g(ω)·sgn ω + σ2·ω (the analytic reference of the tests)."""
    return math.copysign(float(stribeck(omega, tau_c, tau_s, v0)), omega) + sigma2 * omega
