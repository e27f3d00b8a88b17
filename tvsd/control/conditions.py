"""The paper's sufficient gain conditions (22), (23), (25), checked with the numbers.

They are sufficient only (MODEL-NOTES §5): 27 of the 81 Table-5 gain sets violate (22) and still
settle. So a violation is a warning with the numbers, never a refusal.
- (22) Gp > Gd/2
- (23) Gr ≥ (τs + τv_max)/k̃u with k̃u = kM·ku/R (the paper never defines k̃u) and τv_max = J·Δv_max
- (25) 0 < η < kv/J: an η exists when kv > 0; reported with the bound kv/J
"""

from __future__ import annotations

from dataclasses import dataclass

from tvsd.config import Gains, PlantParams


@dataclass(frozen=True)
class Condition:
    name: str  # "(22)", "(23)", "(25)"
    holds: bool
    text: str  # the inequality with the numbers


def check_gains(gains: Gains, plant: PlantParams, dv_max: float, ku: float | None = None) -> list[Condition]:
    ku_eff = plant.ku if ku is None else ku
    ku_tilde = plant.kM * ku_eff / plant.R
    tau_v_max = plant.J * dv_max
    gr_min = (plant.tau_s + tau_v_max) / ku_tilde
    eta_max = plant.kv / plant.J
    return [
        Condition(
            "(22)",
            gains.Gp > gains.Gd / 2,
            f"Gp > Gd/2: {gains.Gp:g} {'>' if gains.Gp > gains.Gd / 2 else '≤'} {gains.Gd / 2:g}",
        ),
        Condition(
            "(23)",
            gains.Gr >= gr_min,
            f"Gr ≥ (τs + J·Δv_max)/k̃u = ({plant.tau_s:.3g} + {tau_v_max:.3g})/{ku_tilde:.3g}"
            f" = {gr_min:.3g} V: Gr = {gains.Gr:g}",
        ),
        Condition(
            "(25)",
            eta_max > 0,
            f"0 < η < kv/J = {eta_max:.4g} 1/s" + ("" if eta_max > 0 else ": no η exists (kv = 0)"),
        ),
    ]


def warnings(conditions: list[Condition]) -> list[str]:
    return [
        f"gain condition {c.name} does not hold: {c.text} (sufficient only; the loop may still "
        f"settle — see MODEL-NOTES §5)"
        for c in conditions
        if not c.holds
    ]
