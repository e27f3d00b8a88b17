"""Config loading: the shipped files load; broken files are refused with file, line and key."""

from __future__ import annotations

import copy
import math
import re
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tvsd.config import Gains, config_dir, load_config
from tvsd.errors import ConfigError, UsageError


def test_shipped_configs_load():
    default = load_config()
    paper = load_config(params="paper")
    assert default.plant.name == "default" and paper.plant.name == "paper"
    assert default.sil is not None and default.sil.vibration.model == "sde"
    assert paper.sil is not None and paper.sil.vibration.model == "sde"
    assert paper.reproduction is not None and len(paper.reproduction.table6_refs_deg) == 7


def test_default_plant_holds_25_rps_with_sane_current():
    """MODEL-NOTES §3: the default set must be physically consistent with a 12 V drive."""
    p = load_config().plant
    omega = 2 * math.pi * 25
    torque = p.kv * omega + p.tau_c
    current = torque / p.kM
    volts = (p.R * current + p.kb * omega) / p.ku
    assert current < 1.0 and volts < 0.6 * load_config().drive.u_max_v


def _base() -> dict:
    return yaml.safe_load((config_dir() / "tvsd.yaml").read_text())


def _write(tmp: Path, data: object) -> Path:
    path = tmp / "tvsd.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    (tmp / "sil.yaml").write_text((config_dir() / "sil.yaml").read_text())
    return path


def _leaves(d: dict, prefix: tuple = ()) -> list[tuple]:
    out = []
    for k, v in d.items():
        if isinstance(v, dict):
            out += _leaves(v, (*prefix, k))
        else:
            out.append((*prefix, k))
    return out


LEAVES = _leaves(_base())
JUNK = st.one_of(
    st.text(max_size=5),
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True),
    st.booleans(),
    st.none(),
    st.lists(st.integers(), max_size=2),
)


def _assert_clear(exc: ConfigError, path: Path) -> None:
    message = str(exc)
    assert re.match(rf"^{re.escape(str(path))}:\d+: ", message), message
    assert "\n" not in message


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(leaf=st.sampled_from(LEAVES), value=JUNK, action=st.sampled_from(["replace", "delete", "add"]))
def test_broken_configs_are_refused_with_file_line_and_key(tmp_path, leaf, value, action):
    data = copy.deepcopy(_base())
    node = data
    for key in leaf[:-1]:
        node = node[key]
    if action == "replace":
        node[leaf[-1]] = value
    elif action == "delete":
        del node[leaf[-1]]
    else:
        node["unexpected_key"] = value
    path = _write(tmp_path, data)
    try:
        load_config(path)
    except ConfigError as exc:
        _assert_clear(exc, path)
        if action == "add":
            assert "unexpected_key" in str(exc)
        elif action == "replace":
            assert leaf[-1] in str(exc) or "sil" in str(exc)
    else:
        # Accepted only when the mutation left a valid file: a replaced value of the right kind,
        # or a deleted key that has a default.
        assert action != "add"


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(max_size=200))
def test_arbitrary_text_never_raises_anything_but_config_error(tmp_path, text):
    path = tmp_path / "x.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(path)  # no text of ≤ 200 characters is a complete valid config
    assert str(info.value).startswith(str(path))


@pytest.mark.parametrize(
    "edit,needle",
    [
        (lambda d: d["plant"].__setitem__("J", -1.0), "plant.J: must be above 0"),
        (lambda d: d["plant"].__setitem__("R", "11 ohm"), "plant.R: expected a number Ω"),
        (lambda d: d["control"]["gains"].__setitem__("Gpp", 1), "did you mean 'Gp'"),
        (lambda d: d["control"].__setitem__("rate_hz", 1e7), "control.rate_hz: must be at most 100000"),
        (lambda d: d["drive"].__setitem__("u_max_v", True), "expected a number"),
        (lambda d: d.__setitem__("sil_profile", "missing.yaml"), "sil_profile: no such file"),
        (
            lambda d: d["imu"].__setitem__("gyro_fs_dps", 300),
            "imu.gyro_fs_dps: must be one of (250, 500, 1000, 2000), got 300",
        ),
        (
            lambda d: d["imu"].__setitem__("poll_interval_s", 0.2),
            "imu.poll_interval_s: must be at most 0.05 s",
        ),
        (lambda d: d["imu"].__setitem__("calibration_file", 3), "imu.calibration_file: expected a file path"),
        (lambda d: d["imu"].__setitem__("sa_axis", "w"), "imu.sa_axis: expected one of x, y, z"),
        (
            lambda d: d["scan"].__setitem__("phi_max_deg", 1.0),
            "scan.phi_min_deg (10) must be below phi_max_deg (1)",
        ),
    ],
)
def test_specific_errors_name_the_key_and_expectation(tmp_path, edit, needle):
    data = _base()
    edit(data)
    path = _write(tmp_path, data)
    with pytest.raises(ConfigError, match=re.escape(needle)):
        load_config(path)


def test_error_line_points_at_the_offending_key(tmp_path):
    text = (config_dir() / "tvsd.yaml").read_text().replace("  J: 6.378e-5", "  J: -6.378e-5")
    path = _write(tmp_path, None)
    path.write_text(text)
    line = next(n for n, ln in enumerate(text.splitlines(), 1) if ln.startswith("  J: -"))
    with pytest.raises(ConfigError, match=rf":{line}: plant.J"):
        load_config(path)


def test_a_devices_own_rule_points_at_its_key_line(tmp_path):
    """The MPU6050's rules (checked by ImuSettings itself, not by a key's bounds) name the key and
    its line, like every other config error."""
    text = (config_dir() / "tvsd.yaml").read_text().replace("  gyro_fs_dps: 250", "  gyro_fs_dps: 300")
    path = _write(tmp_path, None)
    path.write_text(text)
    line = next(n for n, ln in enumerate(text.splitlines(), 1) if ln.startswith("  gyro_fs_dps: 300"))
    with pytest.raises(ConfigError, match=rf":{line}: imu.gyro_fs_dps: must be one of \(250"):
        load_config(path)


def test_bad_effect_in_sil_profile_names_the_file(tmp_path):
    path = _write(tmp_path, _base())
    (tmp_path / "sil.yaml").write_text("effects: ['wobble:amplitude=1']\n")
    with pytest.raises(ConfigError, match=r"sil.yaml:1: effects: unknown effect 'wobble'"):
        load_config(path)


@pytest.mark.parametrize(
    "values,needle",
    [
        ({"Gp": -1.0, "Gd": 1.0, "Gr": 1.0, "G0": 1.0}, "Gp: must be at least 0 V, got -1.0"),
        ({"Gp": 1.0, "Gd": 1.0, "Gr": 1.0, "G0": 0.0}, "G0: must be above 0 1/rad, got 0.0"),
        ({"Gp": 1.0, "Gd": math.nan, "Gr": 1.0, "G0": 1.0}, "Gd: expected a finite number V"),
    ],
)
def test_gains_made_in_code_obey_the_configs_rules(values, needle):
    """The API and the command line build Gains directly: the same option rules apply."""
    with pytest.raises(UsageError, match=re.escape(needle)):
        Gains(**values)


def test_the_daemons_times_and_limits_come_from_the_config(tmp_path):
    cfg = load_config()
    d = cfg.daemon
    assert (d.status_period_s, d.drain_period_s, d.fault_window_s, d.home_timeout_s, d.max_rps) == (
        1.0, 0.02, 2.0, 30.0, 60.0
    )  # fmt: skip
    assert cfg.mcu.link_lost_ms == 50.0 and cfg.can.handler_timeout_s == 2.0 and cfg.imu.calibrate_max_s == 60
    data = _base()
    data["daemon"] = {"max_rps": 0}
    with pytest.raises(ConfigError, match=re.escape("daemon.max_rps: must be above 0 rev/s")):
        load_config(_write(tmp_path, data))
    data = _base()
    data["mcu"] = {"link_timeout_ms": 60}
    with pytest.raises(
        ConfigError, match=re.escape("mcu.link_timeout_ms: must be at most link_lost_ms (50 ms)")
    ):
        load_config(_write(tmp_path, data))
