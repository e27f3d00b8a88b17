"""Pulses (+ IMU and drive log) → points with σ and flags: the scan pipeline in one call."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvsd.scan import beta as B
from tvsd.scan import encoder as E
from tvsd.scan import uncertainty as U
from tvsd.scan.compensation import KnownAccel
from tvsd.scan.geometry import jacobian_beta, triangulate
from tvsd.scan.points import FLAG_COMPENSATED, FLAG_ENCODER, FLAG_NO_IMU, FLAG_VIBRATION, PointCloud
from tvsd.scan.pulses import CleanPulses, PulseStats
from tvsd.scan.settings import ScanSettings


@dataclass(frozen=True)
class ScanResult:
    cloud: PointCloud
    stats: PulseStats
    dropped: int  # optical pulses without the zero pulses (or IMU data) the estimator needs


def process(
    pulses: CleanPulses,
    phi: float,
    gamma: float,
    settings: ScanSettings,
    known: KnownAccel | None = None,
    compensate: bool = True,
    method: str | None = None,
    encoder: E.EncoderLog | None = None,
) -> ScanResult:
    """Points for one aim (φ, γ from the steppers). `known` feeds the compensation and the σ model.

    Without compensation `known` is still used to measure the vibration (σ and the flag). With an
    encoder log, β is read from the encoder instead of the zero-pulse fit (`compensate` is moot).
    """
    flags_all = 0
    if encoder is not None:
        t, beta, sb = E.estimate(pulses, encoder, settings.timer_resolution_s)
        dropped = len(pulses.opt_t) - len(t)
        flags_all |= FLAG_ENCODER
        vib = np.full(len(t), np.nan)
        if known is not None:
            vib = U.vibration_level(known, t, settings)
    else:
        est = B.estimate(pulses, method or settings.estimator, known if compensate else None)
        sb, vib = U.sigma_beta(est, settings, known, pulses)
        t, beta, dropped = est.t, est.beta, est.dropped
        flags_all |= FLAG_COMPENSATED if est.compensated else 0
    a = settings.baseline_m
    n = len(t)
    phis, gammas = np.full(n, phi), np.full(n, gamma)
    x, y, z = triangulate(phis, beta, gammas, a)
    dx, dy, dz = jacobian_beta(phis, beta, gammas, a)
    flags = np.full(n, flags_all, dtype=np.int64)
    flags |= np.where(vib > settings.vibration_threshold, FLAG_VIBRATION, 0)
    if known is None and encoder is None:
        flags |= FLAG_NO_IMU
    cloud = PointCloud(
        t=t,
        phi=phis,
        gamma=gammas,
        beta=beta,
        x=x,
        y=y,
        z=z,
        sigma_x=np.abs(dx) * sb,
        sigma_y=np.abs(dy) * sb,
        sigma_z=np.abs(dz) * sb,
        sigma_beta=sb,
        vibration=vib,
        flags=flags,
    )
    return ScanResult(cloud, pulses.stats, dropped)
