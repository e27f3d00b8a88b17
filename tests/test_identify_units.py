"""Each input unit `tvsctl sim record` writes gives the doctor physical parameters and the hidden
cause (issue 12, item 1). tests/test_doctor.py covers a friction asymmetry under A, N*m and duty;
this adds the one the input map matters most for: a dead zone behind a duty command, found in
volts (duty × u_scale), where the map from duty to volts must be applied before the threshold."""

from __future__ import annotations

import pytest
from test_doctor import analyze, record

J_SIL = 6.378e-5  # the SIL plant's inertia (config/tvsd.yaml plant.J)


@pytest.mark.slow
def test_a_duty_command_with_a_dead_zone_is_named_in_volts(tmp_path, capsys):
    """Seed 5, 30 s staircase, dead zone 0.8 V: named `deadzone` with u0 0.786 V (interval
    0.64-0.88) when written; the tolerance is the doctor's own interval (it must contain the
    truth), J within 15 % (the free fit's spread over seeds at this vibration, as test_doctor),
    damping and Coulomb level positive."""
    path = record(tmp_path, "duty_dz", 5, ["deadzone:u0=0.8"], "--profile", "steps", "--u-unit", "duty")
    res = analyze(capsys, path)
    p = res["baseline"]["params"]
    assert p["J"] == pytest.approx(J_SIL, rel=0.15) and p["damping"] > 0 and p["tau_c"] > 0, p
    assert res["cause"] == "deadzone" and res["units"]["u"] == "V", res["causes"]
    lo, hi = res["effect"]["u0_interval"]
    assert lo <= 0.8 <= hi, res["effect"]
