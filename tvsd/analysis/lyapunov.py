"""Largest Lyapunov exponent of the fitted model along the recorded run, with its confidence interval.

The model's state is (φ, ω) (the current is quasi-static); a tangent vector v is carried along the
recorded trajectory with the Jacobian A = [[0, 1], [∂ω̇/∂φ, ∂ω̇/∂ω]] and renormalised every step
(Benettin's method with one vector). ∂ω̇/∂ω = −(kv + b_ω)/J plus the slope of the friction map;
∂ω̇/∂φ comes from angle-locked torques (imbalance, cogging).

Why the step is exact: A is known only at the samples, so it is held over each sample interval h
and v is moved by exp(A·h), in closed form for 2×2 (`exact_steps`). The former explicit Euler step
(I + A·h) has the eigenvalue 1 + h·∂ω̇/∂ω, whose modulus exceeds 1 once h·∂ω̇/∂ω < −2: a stiff,
strongly damped fit (1 kHz data, a real servo's small inertia) then "grew" perturbations that the
model damps, λ1 came out positive (+1025 1/s on a real servo) and the file was called chaotic.
exp(A·h) has the eigenvalues exp(λ·h): a damped direction shrinks for any h.

Why a confidence interval: λ1 is a time average of the per-step log stretches; its error is
statistical. The run (after a warm-up block in which v aligns) is cut into blocks; the spread of
the block averages gives the standard error (batch means) and a Student-t 95 % interval. The
verdict "chaotic" needs all of:
- the fitted model is physical (J > 0) and dissipative (λ1 + λ2 = mean ∂ω̇/∂ω < 0): a positive
  exponent of a model with negative damping is an unstable fit, not chaos;
- the interval's lower end above 0;
- λ1 above the resolution 1/T: fewer than one e-fold of divergence over the whole kept run cannot
  be told from a neutral direction.
For a spinning shaft the angle direction is neutral (a shifted shaft stays shifted: λ1 ≈ 0) and
speed perturbations decay at ≈ −(kv + b_ω)/J: trajectories under the same disturbance converge,
so irregular speed comes from the disturbance, not from the dynamics (MODEL-NOTES §4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit
from scipy import stats

from tvsd.analysis.simulate import ReducedModel
from tvsd.model import effects as E

BLOCKS = 16  # batch means after the warm-up block: ≥ 10 for a usable t interval
LEVEL = 0.95
MIN_STEPS_PER_BLOCK = 4


@dataclass(frozen=True)
class Lyapunov:
    """λ1 with its interval, the sum λ1 + λ2, and the verdict with its reason."""

    lambda1: float  # 1/s (or per step for a map)
    ci: tuple[float, float]  # LEVEL interval of λ1 (NaN when too short to say)
    lambda_sum: float  # λ1 + λ2: the mean trace of A (for the model, the mean ∂ω̇/∂ω)
    resolution: float  # 1/T of the kept run: a smaller |λ1| is not resolved
    blocks: int
    chaotic: bool
    reason: str

    def as_json(self) -> dict[str, Any]:
        """The doctor's `lyapunov` object: its keys so far (lambda1_per_s, lambda_speed_per_s,
        chaotic), then the interval and the reason."""
        return {
            "lambda1_per_s": self.lambda1,
            "lambda_speed_per_s": self.lambda_sum,
            "chaotic": self.chaotic,
            "lambda1_ci95_per_s": [self.ci[0], self.ci[1]],
            "lambda2_per_s": self.lambda_sum - self.lambda1,
            "resolution_per_s": self.resolution,
            "blocks": self.blocks,
            "reason": self.reason,
        }


def exact_steps(
    a11: np.ndarray, a12: np.ndarray, a21: np.ndarray, a22: np.ndarray, h: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """exp(A_k·h_k) = e^{c_k}·B_k for 2×2 matrices A_k, all k at once: (B (N, 2, 2), c (N,)).

    With T = tr A, M = A − T/2·I, M² = s²·I where s² = T²/4 − det A:
    exp(A h) = e^{T h/2}·(cosh(s h)·I + sinh(s h)/s·M). The larger eigenvalue's growth e^{c} is
    split off (c = (T/2 + Re s)·h), so B stays bounded however stiff A is: no overflow, no Euler.
    """
    tr = a11 + a22
    s2 = 0.25 * tr * tr - (a11 * a22 - a12 * a21)
    real = s2 >= 0
    s = np.sqrt(np.abs(s2))
    x = 2.0 * s * h
    with np.errstate(divide="ignore", invalid="ignore"):
        # real s: e^{-sh}·cosh(sh) = (1 + e^{-2sh})/2, e^{-sh}·sinh(sh)/s = h·(1 − e^{-2sh})/(2sh)
        c_real = 0.5 * (1.0 + np.exp(-x))
        g_real = h * np.where(x > 1e-12, -np.expm1(-x) / x, 1.0 - 0.5 * x)
    # complex s = iω: cos(ωh), sin(ωh)/ω
    wh = s * h
    c_cplx = np.cos(wh)
    g_cplx = h * np.sinc(wh / math.pi)
    diag = np.where(real, c_real, c_cplx)
    g = np.where(real, g_real, g_cplx)
    half = 0.5 * tr
    B = np.empty((len(h), 2, 2))
    B[:, 0, 0] = diag + g * (a11 - half)
    B[:, 0, 1] = g * a12
    B[:, 1, 0] = g * a21
    B[:, 1, 1] = diag + g * (a22 - half)
    c = (half + np.where(real, s, 0.0)) * h
    return B, c


@njit(cache=True, nogil=True)
def log_stretch(B: np.ndarray, c: np.ndarray, v0: np.ndarray) -> np.ndarray:
    """Per-step log growth of one tangent vector under the steps e^{c_k}·B_k (any dimension),
    renormalised every step."""
    n, dim = B.shape[0], B.shape[1]
    v = v0 / np.sqrt(np.sum(v0 * v0))
    w = np.empty(dim)
    out = np.empty(n)
    for k in range(n):
        for i in range(dim):
            acc = 0.0
            for j in range(dim):
                acc += B[k, i, j] * v[j]
            w[i] = acc
        norm = np.sqrt(np.sum(w * w))
        norm = max(norm, 1e-300)  # a step that maps v to 0 (a singular map) ends its direction
        out[k] = c[k] + np.log(norm)
        for i in range(dim):
            v[i] = w[i] / norm
    return out


def from_stretches(
    ell: np.ndarray,
    h: np.ndarray,
    lambda_sum: float,
    *,
    blocks: int = BLOCKS,
    physical: bool = True,
    flow_log_norm: np.ndarray | None = None,
) -> Lyapunov:
    """λ1 and its interval from per-step log stretches `ell` over steps of length `h`; the verdict.

    The first of blocks + 1 equal blocks is the warm-up (the vector aligns with the most unstable
    direction); the rest give the batch means. `flow_log_norm` (len(ell) + 1 values: ln|ẋ| along
    the run) is subtracted as a telescoping sum: a vector along the flow stretches by |ẋ_end|/|ẋ_start|
    over a block without any divergence (a staircase from 0.4 to 47 rad/s: 4.8 e-folds), which
    would read as a positive exponent in every block that speeds up. Bounded, it leaves λ1's limit
    as it is and removes that finite-run bias."""
    if flow_log_norm is not None:
        ell = ell - np.diff(flow_log_norm)
    n = len(ell)
    nb = min(blocks, n // MIN_STEPS_PER_BLOCK - 1)
    if nb < 2:
        lam = float(np.sum(ell) / np.sum(h)) if n else math.nan
        return Lyapunov(lam, (math.nan, math.nan), lambda_sum, math.nan, 0, False, "too short to say")
    size = n // (nb + 1)
    keep = slice(n - nb * size, n)
    e, dt = ell[keep].reshape(nb, size), h[keep].reshape(nb, size)
    per_block = e.sum(axis=1) / dt.sum(axis=1)
    span = float(dt.sum())
    lam = float(e.sum() / span)
    se = float(np.std(per_block, ddof=1)) / math.sqrt(nb)
    half = float(stats.t.ppf(0.5 + LEVEL / 2, nb - 1)) * se
    ci = (lam - half, lam + half)
    resolution = 1.0 / span
    if not physical:
        chaotic, reason = False, "the fitted model is not physical (J ≤ 0): no verdict on chaos"
    elif not lambda_sum < 0:
        chaotic, reason = (
            False,
            f"the fitted model is not dissipative (λ1 + λ2 = {lambda_sum:.3g} ≥ 0): a growing "
            "perturbation means an unstable fit, not chaos",
        )
    elif ci[0] > 0 and lam > resolution:
        chaotic, reason = True, f"λ1 > 0: its {LEVEL:.0%} interval excludes 0"
    elif ci[0] > 0:
        chaotic, reason = False, f"λ1 is below the resolution 1/T = {resolution:.3g}: not resolved"
    else:
        chaotic, reason = False, f"the {LEVEL:.0%} interval of λ1 includes 0 or lies below it"
    return Lyapunov(lam, ci, lambda_sum, resolution, nb, chaotic, reason)


def model_jacobian(
    model: ReducedModel, speed: np.ndarray, phi: np.ndarray | None, effect: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(∂ω̇/∂φ, ∂ω̇/∂ω) of the fitted model at every sample."""
    w = np.asarray(speed, dtype=float)
    kv = np.where(w < 0, model.kv * model.kv_neg_scale, model.kv)
    dwdw = -(kv + model.b_omega) / model.J
    if model.d_stribeck > 0:  # d/dω of Δs·exp(−(ω/v0)²)·sgn ω
        slope = -2.0 * np.abs(w) / model.v0**2 * model.d_stribeck * np.exp(-((w / model.v0) ** 2))
        dwdw = dwdw - slope / model.J
    dwdphi = np.zeros_like(w)
    if phi is not None:
        p = np.asarray(phi, dtype=float)
        if effect[E.E_IMB_AMP] != 0:
            dwdphi += effect[E.E_IMB_AMP] * np.cos(p + effect[E.E_IMB_PHASE]) / model.J
        if effect[E.E_COG_AMP] != 0:
            order = effect[E.E_COG_ORDER]
            dwdphi += effect[E.E_COG_AMP] * order * np.cos(order * p + effect[E.E_COG_PHASE]) / model.J
    return dwdphi, dwdw


def _leading_direction(a21: float, a22: float) -> np.ndarray:
    """The eigenvector of [[0, 1], [a21, a22]] with the larger real eigenvalue (any vector when they
    are complex): started there, the vector needs no alignment (for a spinning shaft, the neutral
    angle direction, which a slowly damped speed direction would take seconds to reach)."""
    disc = 0.25 * a22 * a22 + a21
    lam = 0.5 * a22 + math.sqrt(disc) if disc >= 0 else 0.0
    v = np.array([1.0, lam])
    return v if np.all(np.isfinite(v)) else np.array([1.0, 0.0])


def estimate(
    model: ReducedModel,
    t: np.ndarray,
    speed: np.ndarray,
    phi: np.ndarray | None,
    effect: np.ndarray,
    *,
    blocks: int = BLOCKS,
) -> Lyapunov:
    """λ1 of the fitted model along the recorded (φ, ω), with its interval and the verdict."""
    t = np.asarray(t, dtype=float)
    h = np.diff(t)
    physical = model.J > 0 and math.isfinite(model.J)
    with np.errstate(all="ignore"):
        dwdphi, dwdw = model_jacobian(model, speed, phi, effect)
    dwdphi, dwdw = dwdphi[:-1], dwdw[:-1]
    if len(h) == 0 or not (np.all(np.isfinite(dwdw)) and np.all(np.isfinite(dwdphi))):
        return Lyapunov(math.nan, (math.nan, math.nan), math.nan, math.nan, 0, False, "no usable run")
    lambda_sum = float(np.sum(dwdw * h) / np.sum(h))
    ones, zeros = np.ones_like(h), np.zeros_like(h)
    B, c = exact_steps(zeros, ones, dwdphi, dwdw, h)
    ell = log_stretch(B, c, _leading_direction(float(dwdphi[0]), float(dwdw[0])))
    # the run's own flow vector (ω, ω̇): its ω̇ from the recorded speed, whose noise bounds |ẋ| from
    # below where the shaft stops
    w = np.asarray(speed, dtype=float)
    flow = np.log(np.maximum(np.hypot(w, np.gradient(w, t)), 1e-300))
    return from_stretches(ell, h, lambda_sum, blocks=blocks, physical=physical, flow_log_norm=flow)
