"""Scanning mode, one controller update: speed-reference ramp, model feedforward, anti-windup slip.

Shared by the offline closed-loop simulation (tvsd.sim.closed_loop) and the 10 kHz control thread
(tvsd.control.runner), which each integrate the references in their own order.
"""

from __future__ import annotations

import math

from numba import njit

from tvsd.control.law import robust_law
from tvsd.model.lugre import stribeck


@njit(cache=True, nogil=True)
def feedforward(
    omega: float,
    alpha: float,
    J: float,
    kv: float,
    kM: float,
    kb: float,
    R: float,
    ku: float,
    tau_c: float,
    tau_s: float,
    v0: float,
) -> float:
    """Voltage that holds speed ω and acceleration α on the nominal model (steady current)."""
    torque = J * alpha + kv * omega
    if omega != 0.0:
        torque += math.copysign(stribeck(omega, tau_c, tau_s, v0), omega)
    return (R * torque / kM + kb * omega) / ku


@njit(cache=True, nogil=True, inline="always")
def ramp_toward(value: float, target: float, step: float) -> float:
    """The scanning speed reference: move toward the target by at most `step`."""
    if value < target:
        return min(value + step, target)
    if value > target:
        return max(value - step, target)
    return value


@njit(cache=True, nogil=True, inline="always")
def track(
    phi: float,
    omega: float,
    phi_ref: float,
    omega_ref: float,
    alpha_ref: float,
    max_lag: float,
    use_ff: bool,
    J: float,
    kv: float,
    kM: float,
    kb: float,
    R: float,
    ku: float,
    tau_c: float,
    tau_s: float,
    v0: float,
    Gp: float,
    Gd: float,
    Gr: float,
    G0: float,
    umax: float,
) -> tuple[float, float, float, bool]:
    """The lag beyond ±max_lag slips the angle reference (anti-windup), the model's feedforward
    joins the robust law, the sum stays within ±umax.
    Returns (u, u_ff, phi_ref after a slip, slipped)."""
    eps = phi_ref - phi
    slipped = eps > max_lag or eps < -max_lag
    if slipped:
        phi_ref = phi + math.copysign(max_lag, eps)
        eps = phi_ref - phi
    u_ff = feedforward(omega_ref, alpha_ref, J, kv, kM, kb, R, ku, tau_c, tau_s, v0) if use_ff else 0.0
    u = robust_law(eps, omega_ref - omega, Gp, Gd, Gr, G0, max(umax - abs(u_ff), 0.0)) + u_ff
    return u, u_ff, phi_ref, slipped
