"""Triangulation (paper eqs. 1–3), its β-Jacobian, and aiming with stepper quantisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tvsd.errors import UsageError
from tvsd.scan.geometry import aim, doe_b_target, inverse, jacobian_beta, triangulate
from tvsd.scan.settings import ScanSettings

A = 0.5


def test_equations_by_hand():
    # φ = β = 45°: sin(φ+β) = 1, so x = a/2, y = a(1/2 − 1/2) = 0, z = a/2·tan γ (eqs. 1–3).
    x, y, z = triangulate(math.radians(45), math.radians(45), math.radians(30), A)
    assert x == pytest.approx(A / 2, abs=1e-15)
    assert y == pytest.approx(0.0, abs=1e-15)
    assert z == pytest.approx(A / 2 * math.tan(math.radians(30)), abs=1e-15)


@settings(max_examples=200, deadline=None)
@given(
    phi=st.floats(math.radians(10), math.radians(170)),
    frac=st.floats(0.02, 0.98),
    gamma=st.floats(math.radians(-45), math.radians(45)),
)
def test_inverse_undoes_triangulation(phi, frac, gamma):
    beta = frac * (math.pi - phi)  # any β that closes the triangle
    x, y, z = triangulate(phi, beta, gamma, A)
    p, b, g = inverse(x, y, z, A)
    # Round-off only: the angles come back to 1e-9 rad unless the point is ~on the PL axis.
    assert p == pytest.approx(phi, abs=1e-9)
    assert b == pytest.approx(beta, abs=1e-9)
    if abs(math.cos(phi)) > 1e-3:
        assert g == pytest.approx(gamma, abs=1e-9)


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    phi = rng.uniform(0.3, 2.8, 500)
    beta = rng.uniform(0.05, 0.95, 500) * (np.pi - phi)
    gamma = rng.uniform(-0.7, 0.7, 500)
    h = 1e-7
    plus = np.array(triangulate(phi, beta + h, gamma, A))
    minus = np.array(triangulate(phi, beta - h, gamma, A))
    numeric = (plus - minus) / (2 * h)
    exact = np.array(jacobian_beta(phi, beta, gamma, A))
    # Central difference: truncation ~h²·x''' and round-off ~1e-16/h; both far below 1e-5 relative.
    np.testing.assert_allclose(exact, numeric, rtol=1e-5, atol=1e-6)


def test_inverse_reports_points_no_angles_reach():
    p, b, g = inverse([-1.0, 1.0], [0.0, A / 2], [0.0, 0.3], A)
    assert np.isnan(p[0]) and np.isnan(b[0])  # behind the scanner
    assert np.isnan(g[1])  # φ = 90°: eq. (3) gives z = 0 for every γ


def test_aim_quantises_to_the_stepper_and_lands_near_the_target():
    s = ScanSettings()
    target = doe_b_target(61.0, 7.0, 2.0, A)
    a = aim(*target, s)
    step = 2 * math.pi / s.phi_steps_per_rev
    assert a.phi == pytest.approx(a.phi_steps * step) and a.gamma == pytest.approx(
        a.gamma_steps * 2 * math.pi / 3200
    )
    assert abs(a.phi - math.radians(61.0)) <= step / 2 + 1e-12
    # Half a step (0.98 mrad) at 2 m moves the spot at most ~2 mm in each angle: < 3 mm together.
    assert a.aim_error_m < 3e-3
    # The spot is exactly where eqs. (1)–(3) put the quantised angles and β.
    np.testing.assert_allclose(triangulate(a.phi, a.beta, a.gamma, A), a.spot, atol=1e-12)


@pytest.mark.parametrize(
    ("target", "reason"),
    [
        ((-1.0, 0.0, 0.0), "x must be > 0"),
        ((0.02, 0.2, 0.0), "closer than"),
        ((0.2, -3.0, 0.0), "outside the mirror's travel"),
        ((2.0, 0.0, 3.0), "beyond the rod's"),
        ((2.0, A / 2, 0.1), "at φ = 90°"),
        ((math.nan, 0.0, 0.0), "finite"),
    ],
)
def test_unreachable_targets_are_refused_with_the_reason(target, reason):
    with pytest.raises(UsageError, match=reason) as exc:
        aim(*target, ScanSettings())
    assert "\n" not in str(exc.value)


def test_settings_are_checked():
    with pytest.raises(UsageError, match=r"scan\.baseline_m: must be above 0"):
        ScanSettings(baseline_m=0.0)
    with pytest.raises(UsageError, match=r"scan\.estimator: must be one of centred, causal"):
        ScanSettings(estimator="magic")
    with pytest.raises(UsageError, match="phi_min_deg"):
        ScanSettings(phi_min_deg=100.0, phi_max_deg=90.0)
