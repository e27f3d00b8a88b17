"""Dynamic triangulation, paper eqs. (1)–(3), its β-Jacobian, and the inverse (laser aiming).

Frame of eqs. (1)–(3): the PL sits at (0, a/2, 0) and the SA at (0, −a/2, 0); φ is the PL ray's
angle from −y, β the SA ray's angle from +y, both in the x–y plane, and the rod tilt γ lifts the
point to z = (a/2 − y)·tan γ. With r = a·sin β / sin(φ+β) the PL-to-point distance in that plane
(law of sines), x = r·sin φ and y = a/2 − r·cos φ. All functions take and return numpy arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tvsd.errors import UsageError
from tvsd.scan.settings import ScanSettings

F64 = NDArray[np.float64]


def triangulate(phi: ArrayLike, beta: ArrayLike, gamma: ArrayLike, a: float) -> tuple[F64, F64, F64]:
    """Eqs. (1)–(3): x, y, z (m) from φ, β, γ (rad) and baseline a (m)."""
    phi_, beta_ = np.asarray(phi, dtype=np.float64), np.asarray(beta, dtype=np.float64)
    r = a * np.sin(beta_) / np.sin(phi_ + beta_)
    c = np.cos(phi_)
    x = r * np.sin(phi_)
    y = a * 0.5 - r * c
    z = r * c * np.tan(np.asarray(gamma, dtype=np.float64))
    return x, y, z


def jacobian_beta(phi: ArrayLike, beta: ArrayLike, gamma: ArrayLike, a: float) -> tuple[F64, F64, F64]:
    """∂(x, y, z)/∂β (m/rad), MODEL-NOTES §6: a·sin²φ/s², −a·sinφ·cosφ/s², −tanγ·∂y/∂β."""
    phi_, beta_ = np.asarray(phi, dtype=np.float64), np.asarray(beta, dtype=np.float64)
    s2 = np.sin(phi_ + beta_) ** 2
    sp = np.sin(phi_)
    dx = a * sp * sp / s2
    dy = -a * sp * np.cos(phi_) / s2
    dz = -np.tan(np.asarray(gamma, dtype=np.float64)) * dy
    return dx, dy, dz


def inverse(x: ArrayLike, y: ArrayLike, z: ArrayLike, a: float) -> tuple[F64, F64, F64]:
    """φ, β, γ (rad) that eqs. (1)–(3) map to (x, y, z); NaN where no angles do."""
    x_, y_, z_ = (np.asarray(v, dtype=np.float64) for v in (x, y, z))
    along = a * 0.5 - y_  # r·cos φ
    phi = np.arctan2(x_, along)
    beta = np.arctan2(x_, y_ + a * 0.5)
    with np.errstate(divide="ignore", invalid="ignore"):
        gamma = np.where(along != 0.0, np.arctan(z_ / along), np.where(z_ == 0.0, 0.0, np.nan))
    bad = (x_ <= 0.0) | ~np.isfinite(gamma)
    return np.where(bad, np.nan, phi), np.where(bad, np.nan, beta), np.where(bad, np.nan, gamma)


@dataclass(frozen=True)
class Aim:
    """Stepper positions that point the laser at a target, and where the spot actually lands."""

    phi_steps: int
    gamma_steps: int
    phi: float  # rad, quantised to the stepper
    gamma: float  # rad, quantised
    beta: float  # rad: the SA angle of the spot (what a perfect scan measures)
    spot: tuple[float, float, float]  # m: the lit point (the target's range, quantised angles)
    target: tuple[float, float, float]

    @property
    def aim_error_m(self) -> float:
        return math.dist(self.spot, self.target)


def aim(x: float, y: float, z: float, settings: ScanSettings) -> Aim:
    """Point the PL at (x, y, z): stepper-quantised φ, γ, or UsageError naming why it cannot."""
    a = settings.baseline_m
    where = f"target ({x:g}, {y:g}, {z:g}) m"
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise UsageError(f"{where}: coordinates must be finite numbers")
    if x <= 0.0:
        raise UsageError(f"{where} is unreachable: x must be > 0 (the scanner looks along +x)")
    along = a * 0.5 - y
    r = math.hypot(x, along)
    if r < settings.min_range_m:
        raise UsageError(
            f"{where} is unreachable: {r:.3g} m from the PL, closer than {settings.min_range_m:g} m"
        )
    phi = math.atan2(x, along)
    phi_deg = math.degrees(phi)
    if not settings.phi_min_deg <= phi_deg <= settings.phi_max_deg:
        raise UsageError(
            f"{where} is unreachable: needs φ = {phi_deg:.2f}°, outside the mirror's travel "
            f"[{settings.phi_min_deg:g}, {settings.phi_max_deg:g}]°"
        )
    if along == 0.0 and z != 0.0:
        raise UsageError(f"{where} is unreachable: at φ = 90° eq. (3) gives z = 0 for every γ")
    gamma = math.atan(z / along) if along != 0.0 else 0.0
    if abs(math.degrees(gamma)) > settings.gamma_max_deg:
        raise UsageError(
            f"{where} is unreachable: needs γ = {math.degrees(gamma):.2f}°, beyond the rod's "
            f"±{settings.gamma_max_deg:g}°"
        )
    phi_step = 2.0 * math.pi / settings.phi_steps_per_rev
    gamma_step = 2.0 * math.pi / settings.gamma_steps_per_rev
    n_phi, n_gamma = round(phi / phi_step), round(gamma / gamma_step)
    phi_q, gamma_q = n_phi * phi_step, n_gamma * gamma_step
    # The spot: the quantised ray at the target's range (a surface facing the PL).
    sx, sy = r * math.sin(phi_q), a * 0.5 - r * math.cos(phi_q)
    sz = r * math.cos(phi_q) * math.tan(gamma_q)
    beta = math.atan2(sx, sy + a * 0.5)  # in (0, π − φ): the triangle PL–SA–spot closes
    return Aim(n_phi, n_gamma, phi_q, gamma_q, beta, (sx, sy, sz), (x, y, z))


def doe_b_target(phi_deg: float, gamma_deg: float, range_m: float, a: float) -> tuple[float, float, float]:
    """The target the paper's Design of Experiment B aims at: angles (φ, γ) at a PL range."""
    phi, gamma = math.radians(phi_deg), math.radians(gamma_deg)
    along = range_m * math.cos(phi)
    return (range_m * math.sin(phi), a * 0.5 - along, along * math.tan(gamma))
