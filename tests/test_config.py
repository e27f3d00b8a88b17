"""Config loading: the shipped files load; broken files are refused with file, line and key."""

from __future__ import annotations

import copy
import math
import os
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
    assert cfg.mcu.link_lost_ms == 500.0 and cfg.mcu.late_input_hold
    assert cfg.can.handler_timeout_s == 2.0 and cfg.imu.calibrate_max_s == 60
    data = _base()
    data["daemon"] = {"max_rps": 0}
    with pytest.raises(ConfigError, match=re.escape("daemon.max_rps: must be above 0 rev/s")):
        load_config(_write(tmp_path, data))
    data = _base()
    data["mcu"] = {"link_timeout_ms": 60, "link_lost_ms": 50}
    with pytest.raises(
        ConfigError, match=re.escape("mcu.link_timeout_ms: must be at most link_lost_ms (50 ms)")
    ):
        load_config(_write(tmp_path, data))


# --- issue 13 item 5: hostile and unusual files through `tvsd --check` ------------------------------


def _check(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, list[str]]:
    """`tvsd --check --config path` in process: its exit status and its stderr lines."""
    from tvsd.daemon.main import main

    status = main(["--check", "--config", str(path)])
    return status, capsys.readouterr().err.strip().splitlines()


def _shipped_text() -> str:
    return (config_dir() / "tvsd.yaml").read_text()


@pytest.mark.parametrize(
    "edit,needle",
    [
        (
            lambda t: t.replace("  kv: 2.0e-5", "  kv: 2.0e-5\n  kv: 3.0e-5"),
            "duplicate key 'kv' (first at line",
        ),
        (
            lambda t: t.replace("  kb: 8.526e-3", "  kb: 18446744073709551616"),
            "plant.kb: must be at most 100",
        ),
        (lambda t: t.replace("  kb: 8.526e-3", "  kb: " + "9" * 400), "plant.kb: must be within ±1e+12"),
        (lambda t: t.replace("  kb: 8.526e-3", "  kb: " + "9" * 5000), "a value YAML cannot read"),
        (lambda t: t + "x: " + "[" * 1000 + "]" * 1000 + "\n", "nested more than 16 levels"),
        (lambda t: t + "".join(" " * i + f"k{i}:\n" for i in range(1000)), "nested more than 16 levels"),
        (lambda t: t.replace("sil_profile: sil.yaml", "sil_profile: " + "a" * 300), "(300 characters)"),
        (lambda t: t.replace("    Gp: 3.78", "    Gp: 1e30"), "control.gains.Gp: must be at most 10000 V"),
    ],
)
def test_hostile_files_get_one_line_with_file_and_line_and_exit_2(tmp_path, capsys, edit, needle):
    """Each of these passed --check, or crashed it with a traceback, before issue 13."""
    path = _write(tmp_path, None)
    path.write_text(edit(_shipped_text()))
    status, lines = _check(path, capsys)
    assert status == 2, lines
    assert len(lines) == 1, lines
    assert re.match(rf"^tvsd: {re.escape(str(path))}(:\d+)?: ", lines[0]), lines
    assert needle in lines[0], lines


def test_the_error_names_the_line_of_the_duplicate(tmp_path, capsys):
    text = _shipped_text().replace("  kv: 2.0e-5", "  kv: 2.0e-5\n  kv: 3.0e-5")
    path = _write(tmp_path, None)
    path.write_text(text)
    line = [n for n, ln in enumerate(text.splitlines(), 1) if ln.startswith("  kv: ")][1]
    assert f"tvsd.yaml:{line}: " in _check(path, capsys)[1][0]


@pytest.mark.parametrize(
    "spelling", ["6e-5", "6E-5", "6.0e-5", "0.00006", "6e-05", "+6e-5", "60e-6", "6.e-5"]
)
def test_numbers_in_any_yaml_spelling_are_numbers(tmp_path, spelling):
    """YAML 1.1 (PyYAML) reads 6e-5 as a string; YAML 1.2 and every user read a number."""
    path = _write(tmp_path, None)
    path.write_text(_shipped_text().replace("  J: 6.378e-5", f"  J: {spelling}"))
    assert pytest.approx(6e-5, rel=1e-12) == load_config(path).plant.J


NASTY = st.one_of(
    st.integers(-(2**80), 2**80),
    st.integers(10**15, 10**400),
    st.floats(allow_nan=False, min_value=1e12, max_value=1e308),
    st.sampled_from(["6e-5", "1E3", "-2e+2", ".5e1", "1_000", "0x1F", ".inf", "-.inf", ".nan", "~", "1e999"]),
    st.text(min_size=200, max_size=400),
)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    leaf=st.sampled_from(LEAVES),
    value=NASTY,
    dup=st.booleans(),
    depth=st.sampled_from([0, 0, 20, 200]),
)
def test_fuzzed_files_are_accepted_or_refused_in_one_line_with_exit_2(tmp_path, leaf, value, dup, depth):
    """Huge and odd numbers, long text, a duplicated section and deep nesting: `tvsd --check`
    either accepts the file (exit 0) or says why in one line naming the file (exit 2); never a
    traceback."""
    import contextlib
    import io

    from tvsd.daemon.main import main

    data = copy.deepcopy(_base())
    node = data
    for key in leaf[:-1]:
        node = node[key]
    node[leaf[-1]] = "@VALUE@"
    text = yaml.safe_dump(data, sort_keys=False)
    text = text.replace(
        "'@VALUE@'", value if isinstance(value, str) and value.isascii() else json_dump(value)
    )
    if dup:
        text += "geometry:\n  baseline_m: 0.5\n"
    if depth:
        text += "deep: " + "[" * depth + "]" * depth + "\n"
    path = _write(tmp_path, None)
    path.write_text(text)
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = main(["--check", "--config", str(path)])
    lines = err.getvalue().strip().splitlines()
    if status == 0:
        assert not dup and not depth
        return
    assert status == 2, lines
    assert len(lines) == 1 and lines[0].startswith(f"tvsd: {path}"), lines


def json_dump(value: object) -> str:
    """A YAML scalar for a number or text (JSON is YAML)."""
    import json

    return json.dumps(value)


def test_a_control_character_is_one_line_naming_its_line(tmp_path):
    """Found by the fuzz below: PyYAML's reader error is two lines and carries no line mark."""
    path = tmp_path / "tvsd.yaml"
    path.write_text('plant:\n  name: "a\x1fb"\n')
    with pytest.raises(ConfigError) as err:
        load_config(path)
    assert str(err.value) == f"{path}:2: not valid YAML (control character '\\x1f'); remove it"


def test_a_directory_or_binary_file_as_config_is_one_line_with_the_fix(tmp_path, capsys):
    """`--config DIR` printed "[Errno 21] Is a directory: 'DIR'" (Python's words, no fix)."""
    (tmp_path / "etc").mkdir()
    status, lines = _check(tmp_path / "etc", capsys)
    assert status == 2 and len(lines) == 1 and "is a directory, not a config file" in lines[0], lines
    binary = tmp_path / "tvsd.yaml"
    binary.write_bytes(b"\xff\xfe\x00plant")
    status, lines = _check(binary, capsys)
    assert status == 2 and len(lines) == 1 and "not UTF-8 text" in lines[0], lines


def test_a_device_a_pipe_or_a_huge_file_as_config_is_refused_before_reading(tmp_path, capsys):
    """`--config /dev/zero` (or a FIFO nobody writes) was read forever; a 2 MB file was parsed."""
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    huge = tmp_path / "huge.yaml"
    huge.write_text("#" * (2 << 20))
    for path, needle in ((Path("/dev/zero"), "not a regular file"), (fifo, "not a regular file"),
                         (huge, "a config is a few KB")):  # fmt: skip
        status, lines = _check(path, capsys)
        assert status == 2 and len(lines) == 1 and needle in lines[0], lines


def test_a_sil_profile_that_is_a_directory_is_not_called_missing(tmp_path, capsys):
    path = _write(tmp_path, None)
    (tmp_path / "profiles").mkdir()
    path.write_text(_shipped_text().replace("sil_profile: sil.yaml", "sil_profile: profiles"))
    status, lines = _check(path, capsys)
    assert status == 2 and len(lines) == 1 and "sil_profile: not a regular file" in lines[0], lines


def test_the_tty_worker_mode_is_a_checked_mcu_key(tmp_path, capsys):
    """`mcu.tty_workers` (branch ttyrestore): nice by default (the shipped file says so), a bad
    value is one line with file:line naming the choices, exit 2. Before, only $TVSD_TTY_WORKERS
    chose it, and a typo there silently meant nice."""
    assert load_config().mcu.tty_workers == "nice"
    text = _shipped_text().replace("  tty_workers: nice ", "  tty_workers: fast ")
    assert text != _shipped_text()
    path = _write(tmp_path, None)
    path.write_text(text)
    line = next(n for n, ln in enumerate(text.splitlines(), 1) if ln.startswith("  tty_workers: fast"))
    status, lines = _check(path, capsys)
    assert status == 2 and len(lines) == 1, lines
    want = f"tvsd.yaml:{line}: mcu.tty_workers: expected one of nice, fifo, off, got 'fast'"
    assert want in lines[0], lines
    path.write_text(_shipped_text().replace("  tty_workers: nice ", "  tty_workers: off "))
    assert load_config(path).mcu.tty_workers == "off"  # YAML 1.1's false, meant as the choice


def test_a_bare_off_is_the_choice_off_wherever_off_is_one(tmp_path):
    """YAML 1.1 reads a bare `off` as false: `devices.imu: off` (and sil.yaml's documented
    `vibration.model: off`) were refused as "expected text, got False" before branch ttyrestore."""
    path = tmp_path / "tvsd.yaml"
    path.write_text(_shipped_text().replace("  imu: hardware ", "  imu: off "))
    sil = (config_dir() / "sil.yaml").read_text()
    (tmp_path / "sil.yaml").write_text(sil.replace("model: sde", "model: off"))
    cfg = load_config(path)
    assert cfg.devices.imu == "off"
    assert cfg.sil_or_default.vibration.model == "off"
