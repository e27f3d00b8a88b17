"""Forward simulation of the fitted (reduced) model from a recorded command.

    J·ω̇ = b_u·u_applied − b_ω·ω − level·(kv·ω + τc·sgn ω + Δs·e^{−(ω/v0)²}·sgn ω) − offset + τ_e(φ, t)

The current is quasi-static (L/R ≪ a sample; its lag is applied to the command by the caller),
friction is the LuGre static map, and the effects
library supplies u_applied and τ_e with the plant kernel's own functions, so an extension means
the same thing here as in the SIL plant. Sticking at ω = 0 is handled as Karnopp does: the speed
stays 0 while the net drive effort is below the breakaway level.
Used for the IV instruments (noise-free response to the recorded command) and for the held-out
error: simulation restarted from the measured state at the start of every window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from tvsd.model import effects as E
from tvsd.model.plant import drive_output, shaft_torque


@dataclass(frozen=True)
class ReducedModel:
    J: float
    kv: float
    tau_c: float
    d_stribeck: float
    v0: float
    offset: float
    b_u: float
    b_omega: float
    # friction by direction (friction_asymmetry); 1.0 when symmetric
    kv_neg_scale: float = 1.0
    tc_neg_scale: float = 1.0


def _pack(m: ReducedModel) -> np.ndarray:
    return np.array(
        [m.J, m.kv, m.tau_c, m.d_stribeck, m.v0, m.offset, m.b_u, m.b_omega, m.kv_neg_scale, m.tc_neg_scale]
    )


@njit(cache=True, nogil=True)
def _simulate(
    t: np.ndarray,
    u: np.ndarray,
    w0: np.ndarray,
    phi0: np.ndarray,
    restart: np.ndarray,
    m: np.ndarray,
    eff: np.ndarray,
    substeps: int,
    w_out: np.ndarray,
    phi_out: np.ndarray,
) -> None:
    J, kv, tc, ds, v0, off, bu, bw, kvn, tcn = m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9]
    drift_param = int(eff[E.E_DRIFT_PARAM])
    rel = eff[E.E_DRIFT_REL]
    T = t[-1] - t[0] if len(t) > 1 else 1.0
    w = w0[0]
    phi = phi0[0]
    for k in range(len(t)):
        if restart[k]:
            w = w0[k]
            phi = phi0[k]
        w_out[k] = w
        phi_out[k] = phi
        if k == len(t) - 1:
            break
        h = (t[k + 1] - t[k]) / substeps
        f = 1.0 + rel * (t[k] - t[0]) / T
        Jk, kvk, tck, buk, bwk = J, kv, tc, bu, bw
        if drift_param == 0:
            kvk = kv * f
        elif drift_param == 1:
            Jk = J * f
        elif drift_param == 2:
            buk, bwk = bu / f, bw / f
        elif drift_param == 3:
            buk, bwk = bu * f, bw * f * f
        elif drift_param == 4:
            tck = tc * f
        for s in range(substeps):
            # The command between samples is interpolated (first-order hold): samples are point
            # values of the signal, as the inverse model treats them. Angle-locked torques use
            # the measured angle (the encoder is exact to a count; a simulated angle drifts).
            x = (s + 0.5) / substeps
            ua = drive_output((1.0 - x) * u[k] + x * u[k + 1], eff)
            angle = (1.0 - x) * phi0[k] + x * phi0[k + 1]
            drive = buk * ua - off + shaft_torque(angle, t[k] + (s + 0.5) * h, eff)
            if w < 0.0:
                kve, tce = kvk * kvn, tck * tcn
            else:
                kve, tce = kvk, tck
            breakaway = tce + ds
            if w == 0.0 and abs(drive) <= breakaway:
                continue  # stuck
            sgn = 1.0 if w > 0.0 else (-1.0 if w < 0.0 else math.copysign(1.0, drive))
            fric = tce + ds * math.exp(-((w / v0) ** 2))
            acc = (drive - (kve + bwk) * w - fric * sgn) / Jk
            w_new = w + h * acc
            if w != 0.0 and w_new * w < 0.0:
                w_new = 0.0  # friction cannot reverse the motion within a step
            phi += 0.5 * (w + w_new) * h
            w = w_new


def simulate(
    model: ReducedModel,
    t: np.ndarray,
    u: np.ndarray,
    effect: np.ndarray,
    w_meas: np.ndarray,
    phi_meas: np.ndarray,
    window_s: float | None = None,
    substeps: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Simulated (ω, φ); restarted from the measured state every `window_s` (None: once)."""
    restart = np.zeros(len(t), dtype=np.bool_)
    restart[0] = True
    if window_s is not None:
        restart[np.searchsorted(t, np.arange(t[0], t[-1], window_s))] = True
    w_out = np.empty(len(t))
    phi_out = np.empty(len(t))
    _simulate(
        np.ascontiguousarray(t, dtype=float),
        np.ascontiguousarray(u, dtype=float),
        np.ascontiguousarray(w_meas, dtype=float),
        np.ascontiguousarray(phi_meas, dtype=float),
        restart,
        _pack(model),
        effect,
        substeps,
        w_out,
        phi_out,
    )
    return w_out, phi_out


def no_effect() -> np.ndarray:
    return E.neutral()
