"""The input gain's sign is judged only where the gain is distinguishable from zero (issue 12
items 2 and 7; docs/measurements/gainzero.md). A gain within 3 standard errors of zero (either
sign) is no excitation, refused as bad input; only a significantly negative one says "wrong sign
or unit of u". 3 se: the doctor's significance for a parameter's sign everywhere in sense.py (a
true zero gain passes |z| < 3 with probability 0.9973 under its normal error)."""

from __future__ import annotations

import pytest

from tvsd.analysis import sense
from tvsd.errors import DataFileError

DRIVE = {"J": 1e-4, "damping": 1e-5, "tau_c": 1e-3}
SE = {"damping": 1e-6, "tau_c": 1e-4}


@pytest.mark.parametrize("gain", [-0.0678, 0.0432, 0.0])
def test_a_gain_within_three_se_of_zero_is_no_excitation(gain):
    """810395's −0.0678 ± 0.047 (1.4 se): before, baseline_problem said "the command does not
    accelerate the shaft (input gain −0.0678 ≤ 0): wrong sign or unit of u"."""
    p, se = {**DRIVE, "input_gain": gain}, {**SE, "input_gain": 0.047}
    reason = sense.baseline_problem(p, se)
    assert reason is not None and "wrong sign" not in reason and "no excitation" in reason
    with pytest.raises(DataFileError, match=r"^rec\.csv: no excitation: the fitted input gain .* ± 0\.047"):
        sense.check_excited(p, se, "rec.csv")


def test_a_significantly_negative_gain_is_a_wrong_sign():
    p, se = {**DRIVE, "input_gain": -0.5}, {**SE, "input_gain": 0.047}  # 10.6 se below zero
    sense.check_excited(p, se, "rec.csv")  # not refused: the command did reach the speed
    reason = sense.baseline_problem(p, se)
    assert reason is not None and "wrong sign or unit of u" in reason


def test_a_significant_positive_gain_passes():
    p, se = {**DRIVE, "input_gain": 0.5}, {**SE, "input_gain": 0.047}
    sense.check_excited(p, se, "rec.csv")
    assert sense.baseline_problem(p, se) is None
