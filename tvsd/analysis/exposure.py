"""What a recording lets the doctor see of a hidden effect, measured on the recorded signals.

A closed-loop case's size set from the drive limit says little: the law holds the command where
the scanning speed needs it, so a clip at 0.9 × u_max can lie above every command and a dead
zone below every one (then it is a constant torque, a Coulomb level, in one direction of
rotation). These measures, taken on the recording itself (or on the same case recorded without
the effect: the pilot), state the size in units the test can see:

- saturation: the share of samples whose |u| exceeds u_max, the rms excess in noise units
  (`units`), and the part of the clip's torque the baseline's own columns cannot take
  (`exposed_units`, as the dead zone's): a clip that holds the command at a rail on every step
  is partly a lower input gain, which the baseline absorbs. Given the confirmation's `baseline`
  (closed loop: confirmation_baseline), on the rows and with the columns the clip's confirmation
  uses — after the spin-up (instrument.steady_start), the doctor's baseline (u, its one-sample
  shift, ω, sgn ω, the Stribeck and absorber shapes; a constant only where the unit has an
  offset), band-limited rows; without it, every moving sample with u, ω, sgn ω and a constant;
- dead zone: the share of moving samples where the command is inside the zone, or pushes
  against the motion (there a dead zone and Coulomb friction differ: docs/measurements/cldz.md, "Why, per
  cause"); its width in noise units (`units`, u0·b_u) and the part of its torque a Coulomb level cannot
  take (`exposed_units`: the rms of b_u·(clip(u, ±u0) − its mean per direction of motion) over
  the moving samples) — what the data can show: 0 where the command never enters the zone
  and never pushes against the motion, however wide the zone. Given the confirmation's
  `baseline`, the zone's missing command clip(u, ±u0) less its fit on the confirmation's columns
  over its rows (as the clip's);
- friction asymmetry: the share of moving samples in the less-used direction;
- delay: b_u·rms(u(t) − u(t − τ)) in noise units (matrix.delay_torque) on the recorded command;
- drift: the term's change over the run in noise units (R: Δ·b_u·rms u, kv: Δ·kv·rms ω,
  friction: Δ·τc), as the open-loop table states it; `visible`: the drift's torque Δ·(t/T)·term
  less what the baseline's own columns (u, ω, sgn ω, a constant) absorb, rms over the moving
  samples — what refits over time can see of it (tvsd.analysis.drift); given the confirmation's
  `baseline`, the torque less its fit on the confirmation's columns over its rows (as the clip's);
- imbalance, cogging: the revolutions the shaft's angle spans (max − min of ∫ω dt over 2π): a
  torque periodic N times per revolution shows its period only over ≥ 1/N of a turn.

Noise units are torque over J·σv (tvsd.analysis.matrix).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tvsd.analysis.dataset import Dataset
from tvsd.analysis.matrix import delay_torque
from tvsd.analysis.rules import DEFAULT, Rules
from tvsd.causes import parse_effect

MOVING_RAD_S = 0.5  # |ω| above this: the shaft moves (friction acts by direction)


@dataclass(frozen=True)
class Baseline:
    """A confirmation's baseline: its columns on the rows it fits, and how a full-rate signal
    becomes rows (band-limited, decimated: tvsd.analysis.prep)."""

    X: np.ndarray  # the baseline's columns on the rows used
    rows: np.ndarray  # which of the design's rows are used (bool)
    band_rows: Callable[[np.ndarray], np.ndarray]

    def beyond(self, d: np.ndarray) -> float:
        """rms over the rows of the full-rate signal `d` less its least-squares fit on X."""
        dm = self.band_rows(d)[self.rows]
        if len(dm) < 10:
            return 0.0
        coef, *_ = np.linalg.lstsq(self.X, dm, rcond=None)
        return float(np.sqrt(np.mean((dm - self.X @ coef) ** 2)))


def confirmation_baseline(
    data: Dataset, cause: str = "saturation", rules: Rules = DEFAULT
) -> Baseline | None:
    """The rows and baseline columns on which the closed-loop confirmation judges `cause`
    (closed_checks.instrumented_check): the rows of its instrumented design (moving, after the
    spin-up: instrument.steady_start, spin_only as `rules` say), the doctor's measured baseline
    columns (design.build with the absorber's shapes) on them. None where there is no
    confirmation (no excited reference)."""
    from tvsd.analysis import absorber, instrument
    from tvsd.analysis import design as D
    from tvsd.analysis.prep import Band, prepare

    if not data.closed_loop or not instrument.excited(data):
        return None
    prep = prepare(data, Band())
    rotary = data.units.axis == "rotary"
    measured = absorber.absorb(D.build(prep, data.offset_term, rotary, rules=rules))
    spin = cause in rules.spin_only_for
    iv, _ = instrument.instrumented(prep, data.offset_term, rotary, spin_only=spin, rules=rules)
    return Baseline(measured.X[iv.rows_mask], iv.rows_mask, prep.band_rows)


def exposure(
    effect_text: str | None,
    u: np.ndarray,
    omega: np.ndarray,
    plant: Any,
    sigma_v: float,
    dt: float,
    baseline: Baseline | None = None,
) -> dict[str, float]:
    """The measures above for one effect on recorded command `u` (V) and speed `omega` (rad/s);
    `plant` carries J, kv, R, kM, ku, tau_c; `baseline`: the confirmation's rows and columns
    for a clip's or a dead zone's `exposed_units` and a drift's `visible` (closed loop:
    confirmation_baseline)."""
    if not effect_text:
        return {}
    e = parse_effect(effect_text)
    p = e.params
    b_u = plant.kM * plant.ku / plant.R
    jsv = plant.J * sigma_v
    moving = np.abs(omega) > MOVING_RAD_S
    mag = np.abs(u)
    out: dict[str, float] = {}
    if e.name == "saturation":
        u_max = float(p["u_max"])
        out["share"] = float(np.mean(mag > u_max))
        excess = np.sign(u) * np.maximum(mag - u_max, 0.0)
        out["units"] = b_u * float(np.sqrt(np.mean(excess**2))) / jsv
        if baseline is not None:
            beyond = baseline.beyond(excess)
        else:
            beyond = beyond_baseline(excess, u, omega, moving)
        out["exposed_units"] = b_u * beyond / jsv
    elif e.name == "deadzone":
        u0 = float(p["u0"])
        against = moving & (np.sign(u) != np.sign(omega))
        inside = moving & (mag < u0)
        out["share"] = float(np.mean(inside | against))
        out["units"] = u0 * b_u / jsv
        if baseline is not None:  # the zone's missing command, clip(u, ±u0), beyond the baseline
            out["exposed_units"] = b_u * baseline.beyond(np.clip(u, -u0, u0)) / jsv
        else:
            out["exposed_units"] = b_u * beyond_coulomb(u, omega, u0, moving) / jsv
    elif e.name == "friction_asymmetry":
        pos = float(np.mean(moving & (omega > 0)))
        neg = float(np.mean(moving & (omega < 0)))
        out["share"] = min(pos, neg)
        out["units"] = abs(float(p["ratio"]) - 1.0) * plant.tau_c / jsv
    elif e.name == "delay":
        out["units"] = delay_torque(u, float(p["delay_s"]), b_u, dt) / jsv
    elif e.name == "drift":
        rel = float(p["relative_change"])
        term = {
            "R": b_u * float(np.sqrt(np.mean(u**2))),
            "kv": plant.kv * float(np.sqrt(np.mean(omega**2))),
            "friction": plant.tau_c,
        }[str(p["parameter"])]
        out["units"] = rel * term / jsv
        if baseline is not None:
            torque = _drift_torque(str(p["parameter"]), rel, u, omega, plant)
            out["visible"] = baseline.beyond(torque) / jsv
        else:
            out["visible"] = _drift_visible(str(p["parameter"]), rel, u, omega, plant, moving) / jsv
    elif e.name in ("imbalance", "cogging"):
        angle = np.cumsum(omega) * dt
        out["revolutions"] = float(np.max(angle) - np.min(angle)) / (2 * math.pi)
    return {k: (round(v, 5) if math.isfinite(v) else v) for k, v in out.items()}


def _drift_torque(parameter: str, rel: float, u: np.ndarray, omega: np.ndarray, plant: Any) -> np.ndarray:
    """The drift's torque on every sample: its whole change `rel` times the run's fraction t/T
    times the term it scales. An R drift scales the drive's gain and its back-EMF alike
    (b_u·u − b_ω·ω, what drives the shaft beyond the EMF: at a steady speed only the friction it
    balances), so 15 % of it can be a small torque."""
    tf = np.linspace(0.0, 1.0, len(u))
    term = {
        "R": -(plant.kM * plant.ku / plant.R * u - plant.kM * plant.kb / plant.R * omega),
        "kv": plant.kv * omega,
        "friction": plant.tau_c * np.sign(omega),
    }[parameter]
    return np.asarray(rel * tf * term, dtype=float)


def _drift_visible(
    parameter: str, rel: float, u: np.ndarray, omega: np.ndarray, plant: Any, moving: np.ndarray
) -> float:
    """The rms over the moving samples of the drift's torque not explained by a constant baseline
    (u, ω, sgn ω, a constant)."""
    if np.count_nonzero(moving) < 10:
        return 0.0
    um, wm = u[moving], omega[moving]
    d = _drift_torque(parameter, rel, u, omega, plant)[moving]
    A = np.column_stack([um, wm, np.sign(wm), np.ones_like(wm)])
    coef, *_ = np.linalg.lstsq(A, d, rcond=None)
    return float(np.sqrt(np.mean((d - A @ coef) ** 2)))


def beyond_baseline(d: np.ndarray, u: np.ndarray, omega: np.ndarray, moving: np.ndarray) -> float:
    """rms over the moving samples of `d` (a command-side map's missing command, V) less its least-
    squares fit on the baseline's own columns (u, ω, sgn ω, a constant): what a refit of the
    rigid model cannot absorb of it."""
    if np.count_nonzero(moving) < 10:
        return 0.0
    dm, um, wm = d[moving], u[moving], omega[moving]
    A = np.column_stack([um, wm, np.sign(wm), np.ones_like(wm)])
    coef, *_ = np.linalg.lstsq(A, dm, rcond=None)
    return float(np.sqrt(np.mean((dm - A @ coef) ** 2)))


def beyond_coulomb(u: np.ndarray, omega: np.ndarray, u0: float, moving: np.ndarray) -> float:
    """rms over the moving samples of clip(u, ±u0) less its mean per direction of motion: the
    dead zone's missing command (u − (u − clip)) that one constant per direction, a Coulomb
    level, does not absorb (V)."""
    if not np.any(moving):
        return 0.0
    d = np.clip(u, -u0, u0)
    resid = np.zeros_like(d)
    for side in (omega > 0, omega < 0):
        sel = moving & side
        if np.any(sel):
            resid[sel] = d[sel] - float(np.mean(d[sel]))
    return float(np.sqrt(np.mean(resid[moving] ** 2)))
