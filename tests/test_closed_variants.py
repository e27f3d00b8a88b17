"""The closed-loop matrix's variants as explicit rules (tvsd.analysis.rules, matrix_closed.VARIANTS)
and a clip's exposed units on its confirmation's rows and columns (tvsd.analysis.exposure)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tvsd.analysis import calibrate, crossval, instrument, linescan
from tvsd.analysis import design as D
from tvsd.analysis.dataset import Dataset, load
from tvsd.analysis.matrix_closed import VARIANTS
from tvsd.analysis.prep import Band, prepare
from tvsd.analysis.rules import DEFAULT, Rules
from tvsd.config import load_config
from tvsd.sim.record import record


def test_each_variant_carries_the_switches_it_set_before_as_module_flags() -> None:
    """The variants' rules as the matrix set them in the module flags of calibrate and instrument
    before they became one frozen value (transcribed from matrix_closed.analyse as it was): the
    same names run the same doctor."""
    sat = ("saturation",)
    before = {  # skip folds, reference lines, identified only, expected maps, *_for, iv, ref only
        "ls": (True, True, False, False, sat, sat, (), False, False),
        "lsm": (True, True, False, False, (), (), (), False, False),
        "lsd": (True, True, False, False, (*sat, "drift"), sat, (), False, False),
        "lss": (True, True, False, False, sat, sat, sat, False, False),
        "ls0": (False, False, False, False, sat, sat, (), False, False),
        "ls1": (True, False, False, False, sat, sat, (), False, False),
        "ls2": (True, True, True, True, sat, sat, (), False, False),
        "iv": (True, True, False, False, sat, sat, (), True, False),
        "iv_ref": (True, True, False, False, sat, sat, (), True, True),
    }
    for name, want in before.items():
        v = VARIANTS[name]
        r = v.rules
        got = (r.skip_undetermined_folds, r.lines_of_reference, r.identified_only, r.expected_maps)
        got += (r.identified_for, r.expected_for, r.spin_only_for, v.iv, v.reference_only)
        assert got == want, name
    assert VARIANTS["ls"].rules == DEFAULT


def test_the_rules_are_frozen_and_no_module_flag_is_left_to_leak() -> None:
    """A variant cannot be changed in place, and the flags the matrix used to set (and had to put
    back) are gone from the library modules."""
    with pytest.raises(dataclasses.FrozenInstanceError):
        DEFAULT.identified_for = ()  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        VARIANTS["ls"].iv = True  # type: ignore[misc]
    for module, flag in [
        (calibrate, "SKIP_UNDETERMINED_FOLDS"),
        (calibrate, "LINES_OF_REFERENCE"),
        (crossval, "SKIP_UNDETERMINED_FOLDS"),
        (linescan, "LINES_OF_REFERENCE"),
        (instrument, "IDENTIFIED_ONLY"),
        (instrument, "EXPECTED_MAPS"),
        (instrument, "IDENTIFIED_FOR"),
        (instrument, "EXPECTED_FOR"),
        (instrument, "SPIN_ONLY_FOR"),
    ]:
        assert not hasattr(module, flag), flag


@pytest.fixture(scope="module")
def identify8(tmp_path_factory: pytest.TempPathFactory) -> Dataset:
    """8 s of closed-loop identify on the paper plant (steps and multisine on the reference)."""
    cfg = load_config()
    path = tmp_path_factory.mktemp("variants") / "id.csv"
    record(cfg, path, "identify", 8.0, (), seed=2, rps=10.0)
    return load(path, cfg)


def test_the_rules_on_the_design_reach_the_line_scan(identify8: Dataset) -> None:
    """The line scan reads its rule from the design it is given: the reference's lines in
    closed loop by default, the command's with lines_of_reference off (`ls0`, `ls1`)."""
    prep = prepare(identify8, Band())
    design = D.build(prep, identify8.offset_term, True)
    ref_rows = prep.band_rows(identify8.refs["omega_ref"])
    assert np.array_equal(linescan.excitation_rows(design)[0], ref_rows)
    design.rules = Rules(lines_of_reference=False)
    assert np.array_equal(linescan.excitation_rows(design)[0], design.X[:, 0])


def test_a_clips_exposed_units_are_measured_on_the_confirmations_rows(identify8: Dataset) -> None:
    """exposure.confirmation_baseline: the rows the clip's confirmation fits (after the spin-up,
    instrument.steady_start) and the doctor's baseline columns. A missing command that lies only in
    the spin-up (ending half a second before the steady rows begin, past the band filter's
    reach) is invisible to the confirmation: 0 there, where the measure over the whole file took
    it (> 0). One that lies in the steady rows and is no combination of the baseline's columns
    (a 3 Hz square wave) is seen: > 0."""
    from tvsd.analysis.exposure import MOVING_RAD_S, beyond_baseline, confirmation_baseline

    data = identify8
    base = confirmation_baseline(data)
    assert base is not None
    start = instrument.steady_start(data)
    rate = data.sample_rate_hz
    assert start > rate  # the spin-up lasts over a second: there are rows to leave out
    spin = np.zeros_like(data.u)
    spin[: start - round(0.5 * rate)] = 1.0
    omega = data.speed if data.speed is not None else np.gradient(data.position, data.t)
    assert beyond_baseline(spin, data.u, omega, np.abs(omega) > MOVING_RAD_S) > 0.05
    assert base.beyond(spin) < 1e-6 * float(np.sqrt(np.mean(spin**2)))
    steady = np.where(np.arange(len(data.u)) > start, np.sign(np.sin(2 * np.pi * 3.0 * data.t)), 0.0)
    assert base.beyond(steady) > 0.5
