"""σβ kernels against Monte Carlo, and the measured-spectrum variance against the white case."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tvsd.scan import uncertainty as U
from tvsd.scan.beta import BetaEstimate, lagrange_weights
from tvsd.scan.compensation import KnownAccel

T = 0.05  # one revolution at 20 rev/s
DT = 1e-4  # Monte Carlo grid; knots sit on it


def _estimate(knots: np.ndarray, t_o: np.ndarray) -> BetaEstimate:
    w = lagrange_weights(knots, t_o)
    n = len(t_o)
    return BetaEstimate(t_o, np.zeros(n), knots, w, np.full(n, 2 * math.pi / T), False, "test", 0)


def _centred(n: int, frac: float, t0: float = 0.0) -> BetaEstimate:
    knots = np.tile(np.array([-T, 0.0, T]) + T + t0, (n, 1))
    return _estimate(knots, np.full(n, T + t0 + frac * T))


def _monte_carlo_error(est: BetaEstimate, steps: np.ndarray) -> np.ndarray:
    """e = Σ w_i·U(t_i) − U(t_o) for each realisation (rows of `steps`: U on the DT grid)."""
    idx_k = np.rint(est.knots[0] / DT).astype(int)
    idx_o = round(est.t[0] / DT)
    return steps[:, idx_k] @ est.weights[0] - steps[:, idx_o]


def test_acceleration_kernel_matches_monte_carlo():
    rng = np.random.default_rng(1)
    q, runs = 0.65, 4000  # σv = 0.8069 → q = σv²
    n = round(2 * T / DT) + 2
    accel = rng.normal(0.0, math.sqrt(q / DT), (runs, n))
    speed = np.cumsum(accel, axis=1) * DT
    angle = np.concatenate([np.zeros((runs, 1)), np.cumsum(speed, axis=1)[:, :-1] * DT], axis=1)
    for frac in (0.2, 0.6, 0.9):
        est = _centred(1, frac)
        e = _monte_carlo_error(est, angle)
        predicted = q * U.accel_kernel(est)[0]
        # Sample variance of 4000 Gaussian draws: 2.2 % relative std; 10 % is 4.5σ. The grid's
        # discretisation is O(DT/T) = 0.2 %.
        assert abs(np.var(e) / predicted - 1) < 0.10, frac


def test_speed_kernel_matches_monte_carlo():
    rng = np.random.default_rng(2)
    qw, runs = 3.8e-9, 4000  # the gyro's white rate-noise intensity (density²/2)
    n = round(2 * T / DT) + 2
    speed = rng.normal(0.0, math.sqrt(qw / DT), (runs, n))
    angle = np.concatenate([np.zeros((runs, 1)), np.cumsum(speed, axis=1)[:, :-1] * DT], axis=1)
    est = _centred(1, 0.4)
    e = _monte_carlo_error(est, angle)
    assert abs(np.var(e) / (qw * U.speed_kernel(est)[0]) - 1) < 0.10  # as above: 4.5σ of 4000 draws


def test_measured_spectrum_gives_the_white_variance_for_white_acceleration():
    rng = np.random.default_rng(3)
    q, dt = 0.65, 1e-3
    accel = rng.normal(0.0, math.sqrt(q / dt), 20000)
    known = KnownAccel.build(0.0, dt, accel)
    base = _centred(200, 0.5)
    shifted = np.arange(200) * 0.09 + 1.0  # points spread over the record, each with its own window
    est = _estimate(base.knots + shifted[:, None], base.t + shifted)
    ratio = U.accel_var(est, known, 0.5, ((1.0, known.total),)) / (q * U.accel_kernel(est))
    # Each point's 0.5 s window gives a noisy spectrum (~±30 %); the mean over 200 points is
    # within a few % of 1, and the 1 ms grid's midpoint rule adds < 1 %.
    assert abs(np.mean(ratio) - 1) < 0.06
    # And the measured intensity is σv² itself (E[a²]·dt).
    assert abs(np.mean(known.intensity(est.t, 0.5)) / q - 1) < 0.05


def test_timer_term_matches_quantisation_errors_through_the_estimator():
    from tvsd.scan.beta import estimate
    from tvsd.scan.pulses import OPTICAL, ZERO, clean

    res, fine = 0.5e-6, 1e-10
    zero = np.arange(4001) * T
    opt = zero[:-1] + 0.37 * T
    kind = np.concatenate([np.full(len(zero), ZERO), np.full(len(opt), OPTICAL)])
    t = np.concatenate([zero, opt])
    order = np.argsort(t)
    # Each timestamp off by an independent U(±res/2), as a 0.5 µs timer leaves it when the speed
    # jitter spreads the pulses' sub-tick phases; kept on a 0.1 ns grid so nothing else is lost.
    err_t = np.random.default_rng(4).uniform(-res / 2, res / 2, len(t))
    cp = clean(kind[order], np.rint((t[order] + err_t[order]) / fine).astype(np.int64), fine)
    est = estimate(cp, "centred")
    err = est.beta - 0.37 * 2 * math.pi
    # 4000 points: the sample variance is within ±10 % (4.5σ) of the uniform-quantisation model.
    assert abs(np.var(err) / np.mean(U.timer_var(est, res)) - 1) < 0.10


def test_acceleration_inside_imu_samples_is_in_the_compensated_sigma():
    """The compensation holds each 1 ms IMU mean over its sample; what the acceleration does inside
    the sample is left in β. With every tolerance at zero and an ideal timer, σβ is that term alone
    and must match the Monte Carlo of the compensated estimator (white acceleration, 25 rev/s)."""
    from tvsd.scan.settings import ScanSettings

    rng = np.random.default_rng(5)
    q, runs, h, imu_dt, rev = 0.65, 2000, 5e-5, 1e-3, 0.04  # σv = 0.8069, 25 rev/s
    per = round(imu_dt / h)
    n = round(0.1 / h)  # 100 IMU samples
    accel = rng.normal(0.0, math.sqrt(q / h), (runs, n))
    # Exact angle of a piecewise-constant acceleration on the fine grid, at the grid points.
    speed = np.concatenate([np.zeros((runs, 1)), np.cumsum(accel, axis=1) * h], axis=1)
    angle = np.concatenate(
        [np.zeros((runs, 1)), np.cumsum(speed[:, :-1] * h + accel * h * h / 2, axis=1)], axis=1
    )
    settings = ScanSettings(
        imu_scale_tolerance=0.0,
        model_tolerance=0.0,
        clock_sync_error_s=0.0,
        gyro_noise_density=0.0,
        timer_resolution_s=1e-12,
        vibration_window_s=0.1,
    )
    for frac in (0.2, 0.6, 0.9):
        # Knots and the optical pulse on the fine grid, off the IMU's sample edges.
        i_k = np.array([107, 107 + round(rev / h), 107 + round(2 * rev / h)])
        i_o = i_k[1] + round(frac * rev / h)
        knots, t_o = i_k * h, np.array([i_o * h])
        w = lagrange_weights(knots[None, :], t_o)
        est = BetaEstimate(t_o, np.zeros(1), knots[None, :], w, np.full(1, 2 * math.pi / rev), True, "t", 0)
        err = np.empty(runs)
        var = np.empty(runs // 10)
        for r in range(runs):
            known = KnownAccel.build(0.0, imu_dt, accel[r].reshape(-1, per).mean(axis=1))
            _, phi_k = known.integrals(knots)
            _, phi_o = known.integrals(t_o)
            # What the compensated fit leaves: the angle less the known part, at knots and pulse.
            left_k, left_o = angle[r, i_k] - phi_k, angle[r, i_o] - phi_o[0]
            err[r] = w[0] @ left_k - left_o
            if r < len(var):
                var[r] = U.sigma_beta(est, settings, known, None)[0][0] ** 2  # type: ignore[arg-type]
        # The kernel with the true q: 2000 draws give the sample variance a 3.2 % relative std,
        # and 10 % is 3σ.
        assert abs(np.var(err) / (q * U.cell_kernel(est, 0.0, imu_dt)[0]) - 1) < 0.10, frac
        # σβ with q measured by each run from its ≤ 100 samples (±15 % each, ±1.5 % over 200
        # runs). Without the term σβ is the 1e-12 s timer's alone, ~1e-9 rad against ~2e-5 rad.
        assert abs(np.var(err) / np.mean(var) - 1) < 0.12, (frac, np.var(err), np.mean(var))


def test_unresolved_intensity_ignores_slow_acceleration_and_gyro_noise():
    from tvsd.scan.settings import ScanSettings

    rng = np.random.default_rng(6)
    settings = ScanSettings()
    dt, q = 1e-3, 0.1143  # σv = 0.3381
    t = np.arange(20000) * dt
    fs = 1.0 / dt
    rate_noise = rng.normal(0.0, settings.gyro_noise_density * math.sqrt(fs / 2), len(t) + 1)
    white = rng.normal(0.0, math.sqrt(q / dt), len(t))
    slow = 30.0 * np.sin(2 * math.pi * 25.0 * t)  # a once-a-turn line at 25 rev/s, 30 rad/s²
    est = _centred(200, 0.5)
    shifted = np.arange(200) * 0.09 + 1.0
    est = _estimate(est.knots + shifted[:, None], est.t + shifted)
    est = BetaEstimate(est.t, est.beta, est.knots, est.weights, est.omega, True, "t", 0)
    quiet = KnownAccel.build(0.0, dt, np.diff(rate_noise) * fs)
    noisy = KnownAccel.build(0.0, dt, white + slow + np.diff(rate_noise) * fs)
    per_q = dt * dt / 12.0 * U.speed_kernel(est)
    # The gyro's own noise is not acceleration (it is in σβ through its speed-noise term).
    assert np.mean(U.unresolved_var(est, quiet, settings) / per_q) < 0.1 * q
    # The slow line is resolved by the 1 ms samples and drops out; the white part is measured.
    assert abs(np.mean(U.unresolved_var(est, noisy, settings) / per_q) / q - 1) < 0.06


def test_cell_kernel_is_the_speed_kernel_term_when_knots_sit_on_sample_edges():
    # Every sample then lies between two knots, where K is linear: ∫(K − K̄)² = K₁²·dt³/12 each.
    rev, dt = 0.04, 1e-3
    knots = np.array([[0.0, rev, 2 * rev]]) + 0.5
    est = _estimate(knots, np.array([0.5 + rev + 0.017]))
    got = U.cell_kernel(est, 0.0, dt)[0]
    assert got == pytest.approx(dt * dt / 12.0 * U.speed_kernel(est)[0], rel=1e-6)
    # Off the edges the knots' own samples leave less than that (the mean follows K's kink).
    est_off = _estimate(knots + 0.35 * dt, est.t + 0.35 * dt)
    assert U.cell_kernel(est_off, 0.0, dt)[0] < got
