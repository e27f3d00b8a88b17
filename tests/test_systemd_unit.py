"""systemd/tvsd.service: systemd's own checker accepts it, and the settings the daemon relies on are there.

`systemd-analyze verify` refuses a unit whose ExecStart binary does not exist, and /usr/local/bin/tvsd
exists only on an installed scanner. So the test verifies a copy in a temporary folder whose ExecStart
points at an executable that exists here (`true`); every other line is the shipped file's. verify
exits 0 even for unknown keys or unparsable values (it logs them and ignores the line), so the test
also fails on any message about the unit.
"""

from __future__ import annotations

import shutil
import subprocess
from collections import defaultdict
from pathlib import Path

import pytest

UNIT = Path(__file__).resolve().parent.parent / "systemd" / "tvsd.service"
EXEC = "/usr/local/bin/tvsd"
ANALYZE = shutil.which("systemd-analyze")


def _settings(text: str) -> dict[str, list[str]]:
    """'Section.Key' -> values in order (keys such as DeviceAllow= repeat)."""
    out: dict[str, list[str]] = defaultdict(list)
    section = ""
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        out[f"{section}.{key.strip()}"].append(value.strip())
    return out


def _verify(text: str, tmp_path: Path) -> list[str]:
    """Messages systemd-analyze has about this unit text (with ExecStart made runnable here)."""
    assert ANALYZE is not None
    true = shutil.which("true")
    assert true, "no 'true' executable to stand in for tvsd"
    copy = tmp_path / "tvsd.service"
    copy.write_text(text.replace(EXEC, true))
    res = subprocess.run(
        [ANALYZE, "verify", "--man=no", str(copy)], capture_output=True, text=True, timeout=60
    )
    lines = (res.stdout + res.stderr).splitlines()
    problems = [ln for ln in lines if str(copy) in ln or "tvsd.service" in ln]
    if res.returncode != 0:
        problems.append(f"exit status {res.returncode}: {res.stderr.strip()}")
    return problems


needs_analyze = pytest.mark.skipif(
    ANALYZE is None, reason="systemd-analyze not installed (apt-get install systemd) — cannot verify the unit"
)


@needs_analyze
def test_systemd_analyze_verify_accepts_the_unit(tmp_path):
    text = UNIT.read_text()
    assert f"ExecStart={EXEC} " in text  # the substitution below must hit the shipped line
    assert _verify(text, tmp_path) == []


@needs_analyze
def test_the_verify_check_catches_a_bad_line(tmp_path):
    # Guards the test above: a typo must show up as a problem, not pass silently.
    bad = UNIT.read_text().replace("WatchdogSec=2s", "WatchdogSec=2s\nWatchDogSecs=2s")
    assert any("WatchDogSecs" in p for p in _verify(bad, tmp_path))


def test_key_settings():
    s = _settings(UNIT.read_text())
    expect = {
        "Service.Type": ["notify"],
        "Service.ExecStart": [f"{EXEC} --realtime --config /etc/tvsd/tvsd.yaml"],
        "Service.WatchdogSec": ["2s"],
        "Service.Restart": ["on-failure"],
        "Service.User": ["tvsd"],
        "Service.SupplementaryGroups": ["i2c dialout"],
        "Service.RuntimeDirectory": ["tvsd"],
        "Service.RuntimeDirectoryPreserve": ["restart"],  # the tty workers' record survives a restart
        "Service.StateDirectory": ["tvsd"],
        "Service.LimitMEMLOCK": ["infinity"],
        "Service.DevicePolicy": ["closed"],
        "Service.ProtectSystem": ["strict"],
        "Service.NoNewPrivileges": ["yes"],
        "Service.SystemCallFilter": ["@system-service"],
        "Service.RestrictAddressFamilies": ["AF_UNIX AF_CAN AF_NETLINK"],
    }
    for key, value in expect.items():
        assert s.get(key) == value, f"{key}: expected {value}, unit has {s.get(key)}"
    assert set(s["Service.AmbientCapabilities"][0].split()) == {"CAP_SYS_NICE", "CAP_IPC_LOCK"}
    assert int(s["Service.LimitRTPRIO"][0]) >= 50
    # the I2C buses and the serial ports an MCU can sit on (USB CDC, USB-serial, the Pi's UARTs); nothing else
    serial = {"char-ttyACM rw", "char-ttyUSB rw", "char-ttyAMA rw", "char-ttyS rw"}
    assert set(s["Service.DeviceAllow"]) == {"char-i2c rw"} | serial
    for key in ("RestartSec", "ProtectHome", "PrivateTmp", "ProtectKernelTunables", "ProtectControlGroups"):
        assert f"Service.{key}" in s, f"{key}= missing"


def test_nothing_that_breaks_real_time():
    s = _settings(UNIT.read_text())
    # Each of these would stop SCHED_FIFO, the numba JIT, CAN, or the devices (comments in the unit).
    for key in ("RestrictRealtime", "MemoryDenyWriteExecute", "PrivateNetwork", "PrivateDevices", "CPUQuota"):
        assert f"Service.{key}" not in s, f"{key}= breaks the real-time daemon"
    assert "Service.CPUSchedulingPolicy" not in s  # the daemon picks SCHED_FIFO for its loop thread only
