"""The largest Lyapunov exponent: exact tangent steps, a confidence interval, and a verdict that
needs the interval to exclude 0.

Known answers: a linear system's exponent is its leading eigenvalue (a time-varying triangular one:
the mean of its leading diagonal entry, with the sampling error of that mean); the logistic map at
r = 4 has λ = ln 2 per step; the Lorenz system (σ = 10, ρ = 28, β = 8/3) has λ1 ≈ 0.906 1/s
(Sprott, *Chaos and Time-Series Analysis*, 2003). A SIL recording of the drive is not chaotic (the
model's angle direction is neutral, its speed direction damped), neither is a stiff fit whose
h·∂ω̇/∂ω < −2 (the explicit Euler step called that chaotic).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from tvsd.analysis import lyapunov as LY
from tvsd.analysis.simulate import ReducedModel, no_effect


def _ci_contains(est: LY.Lyapunov, value: float) -> bool:
    return est.ci[0] <= value <= est.ci[1]


def test_exact_steps_match_the_matrix_exponential():
    """Real, complex, repeated and stiff eigenvalues (h·λ down to −5000): exp(A·h) to 1e-12."""
    rng = np.random.default_rng(3)
    mats = [rng.normal(size=(2, 2)) * s for s in (0.1, 1.0, 30.0, 3000.0) for _ in range(25)]
    mats += [np.array([[0.0, 1.0], [0.0, -5e6]]), np.array([[-2.0, 1.0], [0.0, -2.0]])]
    mats += [np.array([[0.0, 1.0], [-4e6, -10.0]]), np.zeros((2, 2))]
    A = np.array(mats)
    h = np.full(len(A), 1e-3)
    B, c = LY.exact_steps(A[:, 0, 0], A[:, 0, 1], A[:, 1, 0], A[:, 1, 1], h)
    for k in range(len(A)):
        ref = expm(A[k] * h[k])
        got = np.exp(c[k]) * B[k]
        scale = max(1.0, float(np.abs(ref).max()))
        assert np.allclose(got, ref, rtol=1e-10, atol=1e-12 * scale), (A[k], got, ref)
    # e^{1000} overflows a float; the growth goes into c, and B stays finite
    B, c = LY.exact_steps(np.zeros(1), np.ones(1), np.zeros(1), np.full(1, 1e6), np.full(1, 1e-3))
    assert np.all(np.isfinite(B)) and c[0] == pytest.approx(1000.0)


@pytest.mark.parametrize("lam1,lam2", [(-50.0, -400.0), (-3000.0, -4000.0)])
def test_constant_stable_systems_give_their_leading_eigenvalue(lam1, lam2):
    """A constant A is deterministic: λ1 is its leading eigenvalue to 1e-9 relative, even when
    h·λ1 = −3 (the Euler step's factor |1 + h·λ1| = 2 would have said +693 1/s)."""
    h = np.full(20000, 1e-3)
    n = len(h)
    # eigenvalues lam1, lam2 in companion form [[0, 1], [−λ1λ2, λ1 + λ2]]
    B, c = LY.exact_steps(np.zeros(n), np.ones(n), np.full(n, -lam1 * lam2), np.full(n, lam1 + lam2), h)
    est = LY.from_stretches(LY.log_stretch(B, c, np.array([1.0, 0.3])), h, lam1 + lam2)
    assert est.lambda1 == pytest.approx(lam1, rel=1e-9)
    assert est.ci[1] < 0 and not est.chaotic


@pytest.mark.parametrize("tau,seed", [(1e-3, 1), (2e-4, 2)])
def test_time_varying_linear_system_recovers_minus_one_over_tau(tau, seed):
    """a11 = −1/τ + ξ_k (ξ white, σ = 0.5/τ), a22 = −5/τ, a12 = 1: λ1 = −1/τ. Its estimate is the
    mean of ξ over the kept steps, whose standard error is σ/√N; the 95 % interval must hold −1/τ
    (fixed seeds) and its half-width must be 1.96·σ/√N within the batch-means' own scatter (±40 %
    for 15 degrees of freedom). τ = 0.2 ms at h = 1 ms: h·λ1 = −5, h·λ2 = −25 (stiff)."""
    rng = np.random.default_rng(seed)
    n, h0 = 200_000, 1e-3
    sigma = 0.5 / tau
    xi = rng.normal(0.0, sigma, n)
    h = np.full(n, h0)
    B, c = LY.exact_steps(-1.0 / tau + xi, np.ones(n), np.zeros(n), np.full(n, -5.0 / tau), h)
    est = LY.from_stretches(LY.log_stretch(B, c, np.array([1.0, 1.0])), h, -6.0 / tau)
    assert _ci_contains(est, -1.0 / tau), est
    kept = est.blocks * (n // (est.blocks + 1))
    expected_half = 1.96 * sigma / math.sqrt(kept)
    half = 0.5 * (est.ci[1] - est.ci[0])
    assert 0.6 * expected_half < half < 1.4 * expected_half, (half, expected_half)
    assert not est.chaotic


def test_logistic_map_is_chaotic():
    """x → 4x(1 − x): λ = ln 2 per step; the interval excludes 0 and holds ln 2."""
    n = 40_000
    x = np.empty(n)
    x[0] = 0.1234
    for k in range(n - 1):
        x[k + 1] = 4.0 * x[k] * (1.0 - x[k])
    B = (4.0 * (1.0 - 2.0 * x)).reshape(n, 1, 1)
    ones = np.ones(n)
    est = LY.from_stretches(LY.log_stretch(B, np.zeros(n), np.ones(1)), ones, -math.inf)
    # λ1 + λ2 = −∞: a 1-D map has no second exponent; the dissipation check does not apply
    assert est.ci[0] > 0 and est.chaotic, est
    assert _ci_contains(est, math.log(2.0)), est


def _expm_taylor(A: np.ndarray, order: int = 14) -> np.ndarray:
    """exp of many small matrices at once (‖A‖ ≲ 0.5 here: the 14th-order remainder < 1e-16);
    scipy's expm takes ~0.3 ms per matrix."""
    out = np.broadcast_to(np.eye(A.shape[1]), A.shape).copy()
    term = out.copy()
    for k in range(1, order + 1):
        term = term @ A / k
        out += term
    return out


def test_lorenz_is_chaotic():
    """The Lorenz flow sampled at h = 0.01 s for 300 s, its Jacobian held over each sample:
    λ1 > 0 with the interval excluding 0, and within 15 % of 0.906 1/s (the held Jacobian is a
    first-order approximation of the flow's tangent map)."""
    s, r, b = 10.0, 28.0, 8.0 / 3.0

    def f(_t, u):
        return [s * (u[1] - u[0]), u[0] * (r - u[2]) - u[1], u[0] * u[1] - b * u[2]]

    h0 = 0.01
    t = np.arange(0.0, 300.0, h0)
    sol = solve_ivp(f, (0, t[-1]), [1.0, 1.0, 20.0], t_eval=t, rtol=1e-8, atol=1e-8, method="DOP853")
    x, y, z = sol.y
    n = len(t) - 1
    J = np.zeros((n, 3, 3))
    J[:, 0, 0], J[:, 0, 1] = -s, s
    J[:, 1, 0], J[:, 1, 1], J[:, 1, 2] = r - z[:-1], -1.0, -x[:-1]
    J[:, 2, 0], J[:, 2, 1], J[:, 2, 2] = y[:-1], x[:-1], -b
    B = _expm_taylor(J * h0)
    h = np.full(n, h0)
    est = LY.from_stretches(LY.log_stretch(B, np.zeros(n), np.ones(3)), h, -(s + 1 + b))
    assert est.chaotic and est.ci[0] > 0, est
    assert est.lambda1 == pytest.approx(0.906, rel=0.15), est


def _model(J: float, kv: float) -> ReducedModel:
    return ReducedModel(J=J, kv=kv, tau_c=1e-3, d_stribeck=0.0, v0=0.03, offset=0.0, b_u=1.0, b_omega=0.0)


def test_a_stiff_servo_fit_is_not_chaotic():
    """A servo-like fit at 1 kHz: J = 1e-5, kv = 5e-2, so ∂ω̇/∂ω = −5000 1/s and h·∂ω̇/∂ω = −5.
    Along a noisy speed trace the exponent is the neutral angle direction's 0 (within the
    resolution), λ1 + λ2 = −5000; the Euler step gave +1386 1/s here (ln 4 per ms)."""
    rng = np.random.default_rng(5)
    t = np.arange(0, 20.0, 1e-3)
    speed = 3.0 * np.sin(2 * math.pi * 0.5 * t) + rng.normal(0, 0.1, len(t))
    phi = np.cumsum(speed) * 1e-3
    est = LY.estimate(_model(1e-5, 5e-2), t, speed, phi, no_effect())
    assert abs(est.lambda1) < est.resolution and not est.chaotic, est
    assert est.lambda_sum == pytest.approx(-5000.0)


def test_an_unphysical_fit_gets_no_chaos_verdict():
    """Negative inertia (a real servo's fit, issue 12) makes ∂ω̇/∂ω > 0: perturbations grow, but
    that is an unstable fit, not chaos; the reason says so."""
    t = np.arange(0, 5.0, 1e-3)
    speed = np.full(len(t), 10.0)
    est = LY.estimate(_model(-1e-5, 5e-3), t, speed, np.cumsum(speed) * 1e-3, no_effect())
    assert est.lambda1 > 0 and est.ci[0] > 0
    assert not est.chaotic and "not physical" in est.reason
    est = LY.estimate(_model(1e-5, -5e-3), t, speed, np.cumsum(speed) * 1e-3, no_effect())
    assert not est.chaotic and "not dissipative" in est.reason


def test_too_short_says_so():
    t = np.arange(0, 5e-3, 1e-3)
    est = LY.estimate(_model(1e-5, 5e-3), t, np.ones(len(t)), None, no_effect())
    assert not est.chaotic and est.reason == "too short to say" and math.isnan(est.ci[0])
    assert set(est.as_json()) >= {"lambda1_per_s", "lambda_speed_per_s", "chaotic", "lambda1_ci95_per_s"}


@pytest.mark.slow
@pytest.mark.parametrize("effects", [[], ["cogging:order=4,amplitude=2e-4"]], ids=["null", "cogging"])
def test_open_loop_sil_recordings_are_not_chaotic(tmp_path, effects):
    """`tvsctl sim record` (the open-loop staircase, 30 s): the paper's model with LuGre friction
    and a white disturbance is not chaotic. With cogging the shaft crawls through its wells near
    zero speed and speeds up to 47 rad/s: the old relative threshold said chaotic (λ1 = 0.14 >
    0.05·0.42); the flow-corrected interval includes 0."""
    from tvsd.analysis.dataset import load
    from tvsd.analysis.doctor import diagnose
    from tvsd.analysis.summary import lyapunov
    from tvsd.cli.main import main
    from tvsd.config import load_config

    out = tmp_path / "rec.csv"
    argv = ["sim", "record", "--out", str(out), "--profile", "steps", "--seconds", "30", "--seed", "3"]
    for e in effects:
        argv += ["--effect", e]
    assert main(argv) == 0
    cfg = load_config()
    dg = diagnose(load(out, cfg), cfg.plant.v0)
    est = lyapunov(dg)  # the doctor's own estimate: its fitted model, the cause it named
    assert not est.chaotic and est.ci[0] < 0 < est.ci[1], est
    assert est.lambda_sum < 0
