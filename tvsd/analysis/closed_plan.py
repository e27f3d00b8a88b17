"""The closed-loop matrix's cases (tvsd.analysis.matrix_closed runs them): which plant, cause,
size and σv each case draws, in which order, and a clip or dead zone sized on the case's own
command (a pilot recording without it).

`plan` goes round by round (every cause and size once, then the next repetition) so a partial
batch is balanced; `plan_cells` is the per-cause plan (σv stratified per cell) whose limits
tvsd.analysis.matrix_limits tabulates.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from tvsd.analysis import matrix as M
from tvsd.config import Config, load_config


def plan(n_null: int, reps: int, sizes: tuple[float, ...], seed: int) -> list[M.Case]:
    """Round by round: in each of `reps` rounds every cause at every size once, and its share of
    the nulls; each case draws its plant, σv (cycling), scanning speed and effect from its index."""
    cfg = load_config()
    names = tuple(M._effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0)))
    order: list[tuple[str, float]] = []
    per_round = -(-n_null // max(reps, 1))
    nulls_left = n_null
    for _ in range(reps):
        order += [(c, m) for c in names for m in sizes]
        k = min(per_round, nulls_left)
        order += [("none", 0.0)] * k
        nulls_left -= k
    order += [("none", 0.0)] * nulls_left
    return [
        _case(cfg, np.random.default_rng([seed, 7, k]), 10_000 * seed + k, cause, m, M.SIGMAS[k % 3])
        for k, (cause, m) in enumerate(order)
    ]


def _case(cfg: Config, g: np.random.Generator, index: int, cause: str, m: float, sigma: float) -> M.Case:
    """One closed-loop case: a plant drawn from the family, its cause at m × the base, σv."""
    plant = M._plant(cfg, g)
    text, torque = None, math.nan
    if cause != "none":
        text, torque = M._effects(plant, cfg.drive.u_max_v, g)[cause](m)
    units = torque / (plant.J * sigma) if math.isfinite(torque) else math.nan
    if cause == "colored_noise":  # the null's spectrum below the corner (matrix.coloured_sigma)
        sigma = M.coloured_sigma(sigma, m * M.COLOUR_TAU_S)
    p = {k2: getattr(plant, k2) for k2 in ("J", "kv", "R", "kM", "tau_c")}
    rps = M.scan_rps(plant, cfg.drive.u_max_v)
    return M.Case(index, cause, m, units, text, "identify", sigma, p, rps)


def round_length(n_null: int, reps: int, sizes: tuple[float, ...]) -> int:
    cfg = load_config()
    names = M._effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0))
    return len(names) * len(sizes) + -(-n_null // max(reps, 1))


def plan_cells(reps: int, sizes: tuple[float, ...], seed: int, nulls: int = 1) -> list[M.Case]:
    """The per-cause plan (as matrix_open.plan, closed loop): `reps` rounds of every cause at every
    size once and `nulls` nulls; the i-th case of a cause and size (offset by its place in the
    round) has σv = SIGMAS[i % 3], so any three consecutive ones of a cell hold every σv. (`plan`
    cycles σv over the whole order: with a round length divisible by 3 a cell kept one σv.)"""
    cfg = load_config()
    names = tuple(M._effects(cfg.plant, cfg.drive.u_max_v, np.random.default_rng(0)))
    order: list[tuple[str, float, int]] = []
    count: Counter[tuple[str, float]] = Counter()
    for _ in range(reps):
        for j, key in enumerate([(c, m) for c in names for m in sizes] + [("none", 0.0)] * nulls):
            order.append((*key, count[key] + j))
            count[key] += 1
    return [
        _case(cfg, np.random.default_rng([seed, 13, k]), 10_000 * seed + k, cause, m, M.SIGMAS[i % 3])
        for k, (cause, m, i) in enumerate(order)
    ]


def case_config(case: M.Case, identify: dict[str, Any] | None = None) -> Config:
    cfg = M.case_config(load_config(), case)
    if identify:
        given: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in identify.items()}
        cfg = dataclasses.replace(cfg, identify=dataclasses.replace(cfg.identify, **given))
    return cfg


def sized(
    case: M.Case, cfg: Config, tmp: Path, seconds: float, keep: bool = False, exposed_deadzone: bool = False
) -> M.Case:
    """A closed-loop saturation set where the command is: the case recorded without it (same
    seed: same noise and excitation) gives the command, and u_max sits m × 1 % below its 99 %
    quantile, as in open loop (matrix.saturation_size). From the drive limit, 0.97–0.90 ×
    u_max lay above every command of a scanning plant held with ≤ 40 % of the drive. `keep`: the
    pilot stays in `tmp` (a cache) and is reused. `exposed_deadzone` (`--exposed-deadzone`, opt-in,
    not measured yet): a dead zone sized by what the pilot exposes, not by u_max
    (docs/measurements/cldz.md: 0.4 % of u_max per 1× gave 0–80 exposed noise units)."""
    if case.cause != "saturation" and not (case.cause == "deadzone" and exposed_deadzone):
        return case
    from tvsd.sim.record import record

    pilot = tmp / f"pilot{case.seed}.csv"
    if not (keep and pilot.exists()):
        record(cfg, pilot, "identify", seconds, (), case.seed, rps=case.rps)
    from tvsd.analysis.dataset import load

    data = load(pilot, cfg)
    u = data.u
    if not keep:
        pilot.unlink()
    if case.cause == "deadzone":
        omega = data.speed if data.speed is not None else np.gradient(data.position, data.t)
        b_u = cfg.plant.kM * cfg.plant.ku / cfg.plant.R
        u0, torque = deadzone_size(u, omega, case.size * 0.5 * cfg.plant.J / b_u)
        units = torque * b_u / (cfg.plant.J * case.sigma_v)
        return dataclasses.replace(case, effect=f"deadzone:u0={u0:.6g}", noise_units=units)
    u_max, excess = M.saturation_size(u, case.size)
    units = excess * cfg.plant.kM * cfg.plant.ku / cfg.plant.R / (cfg.plant.J * case.sigma_v)
    return dataclasses.replace(case, effect=f"saturation:u_max={u_max:.6g}", noise_units=units)


def deadzone_size(u: np.ndarray, omega: np.ndarray, target_v: float) -> tuple[float, float]:
    """The narrowest zone u0 whose torque beyond a Coulomb level (exposure.beyond_coulomb, in
    volts of command) on this command reaches `target_v`, and what it reaches: the torque causes'
    base (m × 0.5·J N·m) in the dead zone's exposed units. Zones up to half the command's 99 %
    point: wider ones stop the drive (a 12 V zone on a 12 V drive: model_mismatch) or lie past
    the doctor's scan (design.py: up to half the largest command). Where none reaches the
    target, the widest, and the row's exposed_units says what it shows."""
    from tvsd.analysis.exposure import MOVING_RAD_S, beyond_coulomb

    moving = np.abs(omega) > MOVING_RAD_S
    top = 0.5 * float(np.quantile(np.abs(u), 0.99)) if len(u) else 0.0
    lo, hi = 0.0, top
    if beyond_coulomb(u, omega, hi, moving) < target_v:
        return hi, beyond_coulomb(u, omega, hi, moving)
    for _ in range(40):  # the exposed torque grows with u0 (more of the command inside)
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if beyond_coulomb(u, omega, mid, moving) < target_v else (lo, mid)
    return hi, beyond_coulomb(u, omega, hi, moving)
