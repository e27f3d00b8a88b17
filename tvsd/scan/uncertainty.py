"""σβ of each point from its error sources, carried to σx, σy, σz (MODEL-NOTES §6 Jacobians).

Every β estimate is a linear functional of the shaft angle at the knots (the zero pulses used) and
at the optical pulse: e = Σ w_i·U(t_i) − U(t_o), where U is the part of the angle the estimator
does not know. Its variance follows exactly from the weights for each noise type:
- timer quantisation: every timestamp off by U(±q/2): var = ω²·q²/12·(Σ w_i² + 1);
- unknown acceleration a: e = ∫K(s)·a(s)ds, K(s) = Σ c_j·(τ_j − s)₊ over the knots τ and
  coefficients c = (w, −1). With the acceleration's autocovariance R measured over the last
  `vibration_window_s` on the IMU grid (dt = 1 ms), var = dt²·Σ_ij K_i·K_j·R(i − j). No spectral
  shape is assumed: the speed loop removes acceleration below its bandwidth and lifts it a little
  near crossover, and a white-noise model would get the error 10 % too small (measured);
- white speed noise of intensity q_w (the gyro's rate noise, which the compensation integrates):
  var = q_w·∫K₁², K₁(s) = Σ c_j·1[s < τ_j] — piecewise constant;
- clock-map error δ between IMU and pulse times (compensation only; pulse–pulse differences share
  one timer): var = δ²·(ω_K(t_o) − Σ w_i·ω_K(t_i))²;
- acceleration inside an IMU sample (`unresolved_var`): the IMU gives 1 ms means and the
  compensation holds each mean over its sample, so it takes out of e = ∫K(s)·a(s)ds only
  Σ_c ā_c·∫_c K = ∫K̄·a, K̄ the cell means of K. What is left, ∫(K − K̄)·a, has for acceleration
  white at intensity q_hf inside the samples var = q_hf·(∫K² − dt·Σ_c K̄_c²) (`cell_kernel`),
  ≈ q_hf·dt²/12·∫K₁²: every sample between the knots leaves an angle step of variance
  q_hf·dt³/12. Nothing the IMU records shows what happens inside its samples; q_hf is the level
  at the top of its band, dt·(R(0) − R(1)) of the IMU series (a once-a-turn line or the loop's
  slow reaction is resolved by the samples and drops out of the difference), less the gyro's
  differentiated rate noise. The drive's acceleration has no such content (its dt·(R(0) − R(1))
  is < 1e-3 of the IMU's in SIL). Without compensation the accel_var sum on the 1 ms grid misses
  the same share of ∫K², which is < 1 % of the variance there.
  Measured in SIL (σv = 0.8069, 25 rev/s, every other error source off): 2.26e-5 rad rms left by
  1 kHz samples (2.22e-5 rad predicted), 3.8e-6 rad with 0.1 ms samples; at 25 rev/s it is a third
  of the compensated σβ², the largest single term. The 0.5 µs timer (3.1e-5 rad) used to hide it.
R is what the estimator leaves unknown: the IMU's and the drive's acceleration without
compensation; with it, the gyro-scale and drive-model tolerances of each. Without an IMU the
white-noise form var = q·∫K² is used with q calibrated on how well the zero pulses predict each
other (`pulse_intensity`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tvsd.scan.beta import BetaEstimate, lagrange_weights
from tvsd.scan.compensation import KnownAccel
from tvsd.scan.pulses import CleanPulses
from tvsd.scan.settings import ScanSettings

F64 = NDArray[np.float64]


def _knots_and_coeffs(est: BetaEstimate) -> tuple[F64, F64]:
    """All knots (zero pulses and the optical pulse), sorted per row, with their coefficients."""
    tau = np.concatenate([est.knots, est.t[:, None]], axis=1)
    c = np.concatenate([est.weights, -np.ones((len(est.t), 1))], axis=1)
    order = np.argsort(tau, axis=1)
    tau = np.take_along_axis(tau, order, axis=1)
    return tau - tau[:, :1], np.take_along_axis(c, order, axis=1)


def accel_kernel(est: BetaEstimate) -> F64:
    """∫K² (s³): β variance per unit white-acceleration intensity."""
    tau, c = _knots_and_coeffs(est)
    # K at each knot τ_k: Σ_j c_j·max(τ_j − τ_k, 0).
    k_at = np.sum(c[:, None, :] * np.maximum(tau[:, None, :] - tau[:, :, None], 0.0), axis=2)
    h = np.diff(tau, axis=1)
    ka, kb = k_at[:, :-1], k_at[:, 1:]
    return np.sum(h / 3.0 * (ka * ka + ka * kb + kb * kb), axis=1)


def speed_kernel(est: BetaEstimate) -> F64:
    """∫K₁² (s): β variance per unit white-speed-noise intensity."""
    tau, c = _knots_and_coeffs(est)
    # On (τ_k, τ_k+1) the step function is the sum of the coefficients of the later knots.
    later = np.cumsum(c[:, ::-1], axis=1)[:, ::-1][:, 1:]
    return np.sum(np.diff(tau, axis=1) * later * later, axis=1)


def accel_var(
    est: BetaEstimate, known: KnownAccel, window_s: float, parts: tuple[tuple[float, F64], ...]
) -> F64:
    """dt²·K̄ᵀ·R·K̄ with R = Σ scale²·R(series) over `parts`, measured before each point."""
    tau = np.concatenate([est.knots, est.t[:, None]], axis=1)
    c = np.concatenate([est.weights, -np.ones((len(est.t), 1))], axis=1)
    dt = known.dt
    first = np.floor((tau.min(axis=1) - known.t0) / dt)
    lags = int(np.ceil(np.max(tau.max(axis=1) - tau.min(axis=1), initial=0.0) / dt)) + 2
    centres = known.t0 + (first[:, None] + 0.5 + np.arange(lags)[None, :]) * dt
    kbar = np.sum(c[:, None, :] * np.maximum(tau[:, None, :] - centres[:, :, None], 0.0), axis=2)
    nfft = 1 << int(np.ceil(np.log2(2 * lags)))
    spec = np.fft.rfft(kbar, nfft, axis=1)
    ck = np.fft.irfft(spec * np.conj(spec), nfft, axis=1)[:, :lags]
    r = np.zeros_like(ck)
    for scale, series in parts:
        if scale:
            # The damped response's acceleration (a − λ·ω): what the angle error integrates.
            r += scale * scale * known.autocovariance(est.t, window_s, lags, known.effective(series))
    return dt * dt * (ck[:, 0] * r[:, 0] + 2.0 * np.sum(ck[:, 1:] * r[:, 1:], axis=1))


def cell_kernel(est: BetaEstimate, t0: float, dt: float) -> F64:
    """∫K² − dt·Σ_c K̄_c² (s³): what piecewise-constant means on the grid t0 + k·dt leave of ∫K²."""
    tau = np.concatenate([est.knots, est.t[:, None]], axis=1)
    c = np.concatenate([est.weights, -np.ones((len(est.t), 1))], axis=1)
    first = np.floor((tau.min(axis=1) - t0) / dt)
    rel = tau - (t0 + first[:, None] * dt)  # from the start of the first cell, ≥ 0
    cells = int(np.ceil(np.max(rel, initial=0.0) / dt)) + 1
    edges = np.arange(cells + 1) * dt
    # ∫ from edge e of K = Σ_j c_j·(τ_j − e)₊²/2; cell means are its differences. K = 0 before the
    # first knot (the weights reproduce constants and lines) and after the last.
    prim = 0.5 * np.sum(c[:, None, :] * np.maximum(rel[:, None, :] - edges[None, :, None], 0.0) ** 2, axis=2)
    kbar = (prim[:, :-1] - prim[:, 1:]) / dt
    return np.maximum(accel_kernel(est) - dt * np.sum(kbar * kbar, axis=1), 0.0)


def unresolved_var(est: BetaEstimate, known: KnownAccel, settings: ScanSettings) -> F64:
    """β variance from the acceleration inside each IMU sample, which its mean does not describe."""
    dt = known.dt
    r = known.autocovariance(est.t, settings.vibration_window_s, 2, known.imu)
    # The gyro's rate noise (per-sample σ² = density²·fs/2), differenced: R(0) − R(1) = 3σ²·fs².
    noise_q = 1.5 * (settings.gyro_noise_density / dt) ** 2
    q_hf = np.maximum(dt * (r[:, 0] - r[:, 1]) - noise_q, 0.0)
    return q_hf * cell_kernel(est, known.t0, dt)


def timer_var(est: BetaEstimate, resolution_s: float) -> F64:
    return est.omega**2 * resolution_s**2 / 12.0 * (np.sum(est.weights**2, axis=1) + 1.0)


def pulse_intensity(pulses: CleanPulses, t: F64, window_revs: int = 20) -> F64:
    """Effective white-acceleration intensity q (rad²/s³) from the zero pulses alone (no IMU).

    Each zero pulse n is predicted from pulses n−2, n−1, n+1 (a quadratic, as the estimators use);
    its angle is known (2π·n), so the miss is a realised estimator error. q = mean(miss²)/∫K² over
    the last `window_revs` pulses. Limitation, measured in SIL (default plant, speed loop closed):
    zero pulses sample the angle once a revolution and cannot see the acceleration above half the
    rotation rate, where the loop no longer cancels it; the centred estimator's σ comes out low by
    1.0–1.5× (coverage 0.73 at 15 rev/s, 0.90 at 20, 0.92 at 25). Points carry FLAG_NO_IMU.
    """
    zt, rev = pulses.zero_t, pulses.zero_rev
    n = len(zt)
    if n < 4:
        return np.full(len(t), np.nan)
    centre = np.arange(2, n - 1)
    idx = np.stack([centre - 2, centre - 1, centre + 1], axis=1)
    ok = np.all(rev[idx] - rev[centre][:, None] == np.array([-2, -1, 1]), axis=1)
    knots = zt[idx] - zt[centre][:, None]
    w = lagrange_weights(knots, np.zeros(len(centre)))
    miss = (w * (2.0 * math.pi * np.array([-2.0, -1.0, 1.0]))).sum(axis=1)
    probe = BetaEstimate(
        t=np.zeros(len(centre)),
        beta=miss,
        knots=knots,
        weights=w,
        omega=np.zeros(len(centre)),
        compensated=False,
        method="probe",
        dropped=0,
    )
    q_each = np.where(ok, miss * miss / accel_kernel(probe), 0.0)
    cum_q = np.concatenate([[0.0], np.cumsum(q_each)])
    cum_n = np.concatenate([[0], np.cumsum(ok)])
    # Pulses whose prediction used only times before t: the one at centre + 1 must be ≤ t.
    end = np.clip(np.searchsorted(zt[centre + 1], t, side="right"), 1, len(centre))
    start = np.maximum(end - window_revs, 0)
    count = cum_n[end] - cum_n[start]
    return np.where(count > 0, (cum_q[end] - cum_q[start]) / np.maximum(count, 1), np.nan)


def vibration_level(known: KnownAccel, t: F64, settings: ScanSettings) -> F64:
    """Measured vibration √q (rad/s^1.5): the paper's σv, from the IMU over the window before t."""
    # The gyro's differentiated rate noise (per-sample variance density²·fs³) adds density²·fs² to
    # E[a²]·dt; it is not vibration.
    noise_q = (settings.gyro_noise_density * settings.imu_rate_hz) ** 2
    return np.sqrt(np.maximum(known.intensity(t, settings.vibration_window_s, known.imu) - noise_q, 0.0))


def sigma_beta(
    est: BetaEstimate,
    settings: ScanSettings,
    known: KnownAccel | None,
    pulses: CleanPulses,
) -> tuple[F64, F64]:
    """(σβ in rad, measured vibration intensity √q of the IMU in rad/s^1.5, NaN without IMU)."""
    var = timer_var(est, settings.timer_resolution_s)
    if known is None:
        var = var + pulse_intensity(pulses, est.t) * accel_kernel(est)
        return np.sqrt(var), np.full(len(est.t), np.nan)
    w = settings.vibration_window_s
    vib = vibration_level(known, est.t, settings)
    var = var + unresolved_var(est, known, settings)
    if est.compensated:
        # Independent gyro-scale and drive-model errors: each leaves its share of its own series.
        parts = ((settings.imu_scale_tolerance, known.imu), (settings.model_tolerance, known.drive))
        var = var + accel_var(est, known, w, parts)
        # Gyro rate noise, white over the IMU band fs/2: intensity σ²/fs = density²/2.
        q_w = 0.5 * settings.gyro_noise_density**2
        var = var + q_w * speed_kernel(est)
        om_k, _ = known.integrals(est.knots.ravel())
        om_o, _ = known.integrals(est.t)
        swing = om_o - np.sum(est.weights * om_k.reshape(est.knots.shape), axis=1)
        var = var + (settings.clock_sync_error_s * swing) ** 2
    else:
        # The whole acceleration, IMU and drive together: the loop's reaction cancels the
        # disturbance below its bandwidth, and only their sum's spectrum shows it.
        var = var + accel_var(est, known, w, ((1.0, known.total),))
    return np.sqrt(var), vib
