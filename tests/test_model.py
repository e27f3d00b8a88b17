"""The drive model against analytic results (issue 2, item 6)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from tvsd.config import VibrationConfig, load_config
from tvsd.control.setup import Setup
from tvsd.model.lugre import lugre_step, steady_friction, stribeck
from tvsd.sim import runs

OFF = VibrationConfig(model="off")


@pytest.fixture(scope="module")
def cfg():
    return load_config()


def _steady_speed(p, u: float) -> float:
    """Solve kM·(ku·u − kb·ω)/R = kv·ω + g(ω)·sgn ω + σ2·ω for ω (the open-loop steady state)."""

    def balance(w: float) -> float:
        motor = p.kM * (p.ku * u - p.kb * w) / p.R
        return motor - p.kv * w - steady_friction(w, p.tau_c, p.tau_s, p.v0, p.sigma2)

    return brentq(balance, 1e-6, 1e4)


@pytest.mark.parametrize("u", [3.0, 6.0, 12.0])
def test_steady_speed_matches_the_torque_balance(cfg, u):
    setup = Setup.from_config(cfg, vibration=OFF)
    # 30 s = 12.5 mechanical time constants (2.4 s): the transient left is e^-12.5 ≈ 4e-6.
    trace = runs.open_loop(setup, np.full(300_000, u), decim=1000)
    expected = _steady_speed(cfg.plant, u)
    assert trace.omega[-1] == pytest.approx(expected, rel=1e-4), "steady speed off the torque balance"


def test_electrical_step_follows_the_first_order_response(cfg):
    # A huge inertia holds the shaft still, leaving L·di/dt = ku·u − R·i.
    plant = dataclasses.replace(cfg.plant, J=1e6)
    setup = Setup.from_config(dataclasses.replace(cfg, plant=plant), vibration=OFF)
    u = 6.0
    trace = runs.open_loop(setup, np.full(50, u), decim=1)
    i_ss = plant.ku * u / plant.R
    exact = i_ss * (1 - np.exp(-trace.t * plant.R / plant.L))
    # RK4 at z = −R·dt/L = −0.85 has stability function 0.43065 against e^z = 0.42741: the worst
    # error is 0.33 % of i_ss, after the first step; allow 0.5 %.
    assert np.max(np.abs(trace.current - exact)) < 0.005 * i_ss


@pytest.mark.parametrize("omega", [-150.0, -2.0, -0.02, 0.01, 0.029, 0.5, 30.0, 157.0])
def test_lugre_steady_friction_is_the_static_map(cfg, omega):
    p = cfg.plant
    z, h = 0.0, 1e-3
    for _ in range(20000):  # 20 s: ≥ 140 bristle time constants even at 0.01 rad/s (0.14 s)
        z, tau = lugre_step(z, omega, h, p.tau_c, p.tau_s, p.v0, p.sigma0, p.sigma1, 1.0)
    expected = steady_friction(omega, p.tau_c, p.tau_s, p.v0, p.sigma2) - p.sigma2 * omega
    assert tau == pytest.approx(expected, rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("omega,h", [(157.0, 1e-4), (0.05, 1e-4), (-3.0, 1e-3), (20.0, 1e-5)])
def test_exact_bristle_step_matches_a_fine_reference(cfg, omega, h):
    p = cfg.plant
    z0 = -0.5 * p.tau_s / p.sigma0
    g = stribeck(omega, p.tau_c, p.tau_s, p.v0)
    ref = solve_ivp(
        lambda t, z: omega - p.sigma0 * abs(omega) * z / g,
        (0, h),
        [z0],
        method="Radau",
        rtol=1e-12,
        atol=1e-16,
        dense_output=True,
    )
    z1, tau_mean = lugre_step(z0, omega, h, p.tau_c, p.tau_s, p.v0, p.sigma0, p.sigma1, 1.0)
    assert z1 == pytest.approx(ref.y[0, -1], rel=1e-8, abs=1e-14)
    # The returned torque is the mean of σ0·z + σ1·ż over the step.
    ts = np.linspace(0, h, 20001)
    zs = ref.sol(ts)[0]
    mean_z = np.trapezoid(zs, ts) / h
    assert tau_mean == pytest.approx(p.sigma0 * mean_z + p.sigma1 * (z1 - z0) / h, rel=1e-6)


def test_explicit_rk4_on_the_bristle_would_diverge(cfg):
    """Why the exact step (MODEL-NOTES §2): RK4's stability ends at |λh| ≈ 2.79."""
    p = cfg.plant
    lam_h = p.sigma0 * 157.0 / p.tau_c * 1e-4
    assert lam_h > 2.79


def _noise_run(cfg, vib: VibrationConfig, seconds: float) -> runs.Trace:
    setup = Setup.from_config(cfg, vibration=vib, effects=())
    return runs.open_loop(setup, np.zeros(round(seconds / setup.dt)), decim=1)


def test_ou_vibration_has_the_configured_variance_and_correlation(cfg):
    vib = VibrationConfig(model="ou", sigma_v=0.8, tau_n_s=0.005)
    a = _noise_run(cfg, vib, 100.0).disturbance
    # 100 s / (2·5 ms) ≈ 1e4 independent samples: the variance has a relative std of
    # sqrt(2/1e4) = 1.4 %; 5 standard deviations is 7 %.
    assert np.var(a) == pytest.approx(0.8**2, rel=0.07)
    lag = round(0.005 / 1e-4)
    rho = np.corrcoef(a[:-lag], a[lag:])[0, 1]
    assert rho == pytest.approx(math.exp(-1), abs=0.05)


def test_literal_sde_increments_have_variance_sigma2_dt(cfg):
    vib = VibrationConfig(model="sde", sigma_v=0.8069)
    a = _noise_run(cfg, vib, 10.0).disturbance  # −dW·σ/dt per step, white
    dt = 1e-4
    # 1e5 independent samples: variance relative std 0.45 %; allow 5σ.
    assert np.var(a * dt) == pytest.approx(0.8069**2 * dt, rel=0.025)
    assert abs(np.corrcoef(a[:-1], a[1:])[0, 1]) < 5 / math.sqrt(len(a))


def test_settling_time_converges_in_dt(cfg):
    """MODEL-NOTES §7: dt = 1e-4 s is within 0.3 % of a 10× finer step."""
    from tvsd.sim import experiments

    paper = load_config(params="paper")
    coarse = experiments.step(paper, 20.0, 0.1).settling_time_s
    # Same 10 kHz controller, plant integrated 10× finer: only the integration error differs.
    fine = experiments.step(paper, 20.0, 0.1, substeps=10).settling_time_s
    # One coarse sample (1e-4 s) is 0.3 % of the 0.034 s settling time.
    assert abs(coarse - fine) <= 1e-4 + 1e-9


def test_the_law_is_negative_feedback():
    from tvsd.control.law import robust_law

    assert robust_law(0.1, 0.0, 1.0, 1.0, 1.0, 10.0, 12.0) > 0  # behind the reference: push forward
    assert robust_law(0.0, -1.0, 1.0, 1.0, 1.0, 10.0, 12.0) < 0  # moving past it: brake
    assert robust_law(10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 12.0) == 12.0  # saturated to the drive
