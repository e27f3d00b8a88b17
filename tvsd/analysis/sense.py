"""Checks before any verdict: is the recording analysable, and does the fit make physical sense?

A recording that cannot be identified (too short, no excitation, absurd values) is bad input:
DataFileError, exit status 2, one line. A fit that breaks physics (negative inertia or damping,
a threshold outside the commands, a delay the time constant cannot show) is not a cause: the
doctor reports `model_mismatch` with the reason.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tvsd.analysis.dataset import Dataset
from tvsd.errors import DataFileError

MIN_ROWS = 500  # below this a 7-parameter fit with its noise model is not identifiable
MIN_SECONDS = 1.0
HUGE = 1e12  # larger values than this are not a measured speed, angle or command
TINY = 1e-9  # a command span (V, A, N·m or duty) or speed (rad/s) this small is no signal: 1e-300
# values made the fit's sums of squares underflow (numpy warnings, then a ZeroDivisionError, exit 70)


def check_recording(d: Dataset) -> None:
    where = d.path or d.name
    n = len(d.t)
    if n < MIN_ROWS or d.duration_s < MIN_SECONDS:
        raise DataFileError(
            f"{where}: only {n} rows ({d.duration_s:.3g} s); the doctor needs at least {MIN_ROWS} rows "
            f"and {MIN_SECONDS:g} s of a moving drive (record longer)"
        )
    cols: dict[str, np.ndarray] = {"u": d.u, "phi": d.position}
    if d.speed is not None:
        cols["omega"] = d.speed
    for name, x in cols.items():
        big = np.nonzero(~(np.abs(x) < HUGE))[0]
        if len(big):
            raise DataFileError(
                f"{where}: row {int(big[0]) + 1} of the data: {name} = {x[big[0]]:g} is not a plausible "
                "measurement (overflow or a unit error); repair or cut those rows"
            )
    span = float(np.ptp(d.u))
    if span <= TINY:
        seen = f"is constant ({d.u[0]:g})" if span == 0.0 else f"varies by only {span:.3g} (at most {TINY:g})"
        raise DataFileError(
            f"{where}: the command u {seen}: no excitation, nothing to identify "
            "(record steps, a multisine or `tvsctl identify`)"
        )
    speed = d.speed if d.speed is not None else np.gradient(d.position, d.t)
    if float(np.ptp(speed)) <= TINY or float(np.max(np.abs(speed))) <= TINY:
        raise DataFileError(
            f"{where}: the speed never changes (by more than {TINY:g}): the drive did not move (is the "
            "motor connected, the speed column right?)"
        )


def unexcited(p: dict[str, float], se: dict[str, float]) -> str | None:
    """What was seen when the fitted input gain is not distinguishable from zero (|gain| < 3 se,
    either sign), or None. The command then did not reach the speed: the drive held in its
    friction and the shaft moved, if at all, by something else (a vibration). Its sign says
    nothing about u's (docs/measurements/gainzero.md: null 810395, gain −0.0678, stall torque
    0.98 τc at the command's peak). A NaN gain or error is not judged here (baseline_problem)."""
    g, e = p["input_gain"], se.get("input_gain", 0.0)
    if abs(g) < 3 * e:
        return f"the fitted input gain {g:.3g} ± {e:.2g} is within 3 standard errors of zero"
    return None


def check_excited(p: dict[str, float], se: dict[str, float], where: str) -> None:
    """DataFileError (exit 2) when the command did not reach the speed (unexcited)."""
    seen = unexcited(p, se)
    if seen is not None:
        raise DataFileError(
            f"{where}: no excitation: {seen}, so the command did not move the drive (the shaft "
            "moved, if at all, by something else); record a command that moves it past its "
            "friction (larger steps or a multisine, or `tvsctl identify`)"
        )


def baseline_problem(p: dict[str, float], se: dict[str, float]) -> str | None:
    """Why the baseline's parameters are not a physical drive, or None. A gain within 3 se of
    zero is no excitation, refused before this (check_excited); a caller that does not refuse
    gets it as a reason."""
    seen = unexcited(p, se)
    if seen is not None:
        return f"the command barely moves the shaft ({seen}): no excitation reached the speed"
    if not p["input_gain"] > 0:
        return (
            f"the command does not accelerate the shaft (input gain {p['input_gain']:.3g} ± "
            f"{se.get('input_gain', 0.0):.2g}, not above zero and at least 3 standard errors from it): "
            "wrong sign or unit of u, or the speed is not this motor's"
        )
    if not p["J"] > 0:
        return f"the fitted inertia is not positive (J = {p['J']:.3g})"
    # A negative viscous or Coulomb term alone is not unphysical: with the Stribeck column they
    # share one friction curve (nearly collinear below v₀ on a stick-slip drive), and a misfit
    # moves that split by more than its standard errors say (docs/measurements/stickslip.md).
    # Friction that pushes the shaft is unphysical.
    active = friction_pushes(p, se)
    if not p["damping"] > -3 * se.get("damping", 0.0) and active:
        return (
            f"the fitted damping is negative (kv = {p['damping']:.3g}) and the friction pushes the shaft "
            f"at |ω| = {p.get('friction_speed', math.nan):.3g}{_torque(p)}: the rigid model does not hold"
        )
    if not p["tau_c"] > -3 * se.get("tau_c", 0.0) and active:
        return (
            f"the fitted Coulomb friction is negative (τc = {p['tau_c']:.3g}) and the friction pushes "
            f"the shaft at |ω| = {p.get('friction_speed', math.nan):.3g}{_torque(p)}"
        )
    return None


def friction_pushes(p: dict[str, float], se: dict[str, float]) -> bool:
    """Whether the fitted friction map is below zero by more than 3 standard errors at some
    speed the recording visits (an active friction). Without the map (a caller that does not
    compute it) a negative term counts as before."""
    if "friction_min" not in p:
        return True
    return not p["friction_min"] > -3 * se.get("friction_min", 0.0)


def _torque(p: dict[str, float]) -> str:
    return f" (friction {p['friction_min']:.3g})" if "friction_min" in p else ""


def friction_map(
    names: tuple[str, ...], theta: np.ndarray, cov: np.ndarray, J: float, v0: float, speeds: np.ndarray
) -> tuple[float, float, float]:
    """The fitted friction effort F(v) = kv·v + τc + ds·e^{−(v/v₀)²} (the rigid model's c, f, s
    columns times J) at the speeds `speeds` > 0, where it is most negative relative to its
    standard error: (F, its standard error, v). Friction is dissipative, F(v) ≥ 0, at every speed;
    its separate terms need not be (a Stribeck curve descends). J is taken as known, as for the
    terms' own errors."""
    k = len(theta)
    G = np.zeros((len(speeds), k))
    for j, name in enumerate(names[:k]):
        if name == "c":
            G[:, j] = speeds
        elif name == "f":
            G[:, j] = 1.0
        elif name == "s":
            G[:, j] = np.exp(-((speeds / v0) ** 2))
    F = -J * (G @ theta)
    var = np.einsum("ij,jk,ik->i", G, cov, G)
    err = abs(J) * np.sqrt(np.clip(var, 0.0, None))
    i = int(np.argmin(F / np.maximum(err, 1e-300)))
    return float(F[i]), float(err[i]), float(speeds[i])


def effect_problem(
    cause: str, e: dict[str, Any], u: np.ndarray, time_constant_s: float, fs: float
) -> str | None:
    """Why the best extension's parameters are not physical, or None."""
    top = float(np.max(np.abs(u)))
    if cause == "deadzone" and not 0 < float(e["u0"]) < 0.9 * top:
        return f"the dead zone {float(e['u0']):.3g} is outside the commands (|u| ≤ {top:.3g})"
    if cause == "saturation":
        share = float(np.mean(np.abs(u) > float(e["u_max"])))
        if share < 0.01:
            return f"the saturation {float(e['u_max']):.3g} is above almost every command (|u| ≤ {top:.3g})"
    if cause == "delay":
        d = float(e["delay_s"])
        if not (1.0 / fs <= d < time_constant_s):
            return (
                f"the delay {1e3 * d:.3g} ms is not shorter than the drive's time constant "
                f"({1e3 * time_constant_s:.3g} ms) that lets it be seen"
            )
    if cause == "friction_asymmetry":
        ratio = float(e["ratio"])
        if not (math.isfinite(ratio) and ratio > 0):
            return f"the friction by direction is not positive both ways (ratio {ratio:.3g})"
    if cause == "drift" and not abs(float(e["relative_change"])) < 0.9:
        return f"the fitted drift ({100 * float(e['relative_change']):+.0f} %) is beyond what a drive does"
    return None
