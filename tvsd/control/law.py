"""The robust law of paper eq. (18) with the sign that makes it negative feedback.

    u = Gp·tanh(ε) + Gd·tanh(ε̇) + Gr·tanh(G0·ε),   ε = φr − φ,   |u| ≤ u_max

Eq. (18) as printed (with ε = φr − φ) is positive feedback: a 20° step runs away (MODEL-NOTES §1).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, nogil=True)
def robust_law(eps: float, eps_dot: float, Gp: float, Gd: float, Gr: float, G0: float, u_max: float) -> float:
    u = Gp * math.tanh(eps) + Gd * math.tanh(eps_dot) + Gr * math.tanh(G0 * eps)
    if u > u_max:
        return u_max
    if u < -u_max:
        return -u_max
    return u
