"""tvsctl imu through tvsctl's own main(): exit statuses, JSON contract, the imbalance line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tvsd.cli import main as cli
from tvsd.cli.imu import dominant_line, read_samples, run_capture, sa_alpha
from tvsd.hw.imu_clock import ManualClock
from tvsd.hw.imu_settings import ImuSettings
from tvsd.sim.imu_motion import ArrayMotion
from tvsd.sim.mpu6050 import sil_pair


@pytest.fixture(autouse=True)
def imu_command(monkeypatch):
    monkeypatch.setitem(cli.COMMANDS, "imu", "tvsd.cli.imu")
    for name in [n for n in cli.COMMANDS if n != "imu"]:  # not tested here: keep them out
        monkeypatch.delitem(cli.COMMANDS, name)


def run(capsys, *argv):
    status = cli.main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def test_capture_sil_shows_the_imbalance_line_at_the_rotation_rate(capsys, tmp_path):
    status, out, err = run(
        capsys,
        "imu",
        "capture",
        "--sil",
        "--seconds",
        "5",
        "--json",
        "--out",
        str(tmp_path / "s.csv"),
        "--plot",
        str(tmp_path / "s.png"),
    )
    assert status == 0, err
    r = json.loads(out)
    # 5 s record: bins 0.2 Hz; the flat-top lobe centroid lands well inside one bin
    assert abs(r["dominant_hz"] - 25.0) < 0.2
    # line 2 rad/s^2; flat-top reads amplitude to ~0.1 %, DLPF and differentiator lose ~0.2 %,
    # and the OU vibration adds a little: 5 %
    assert abs(r["peak_rad_s2"] - 2.0) < 0.1
    for name in ("pl", "sa"):
        s = r["sensors"][name]
        assert set(s) >= {"rate_hz", "samples", "overflows", "errors"}
        assert s["lost"] == 0 and s["errors"] == 0 and s["samples"] > 4500
    assert abs(r["sensors"]["pl"]["rate_hz"] - 1027) < 0.5  # the twin's +2.7 % clock
    assert (tmp_path / "s.png").stat().st_size > 10_000
    data = read_samples(tmp_path / "s.csv")
    assert len(data["pl"]["t"]) == r["sensors"]["pl"]["samples"]
    assert abs(np.mean(data["sa"]["accel"][:, 2]) - 9.8) < 0.4


def test_capture_without_the_effect_shows_no_line_at_the_rotation_rate(capsys):
    status, out, _ = run(capsys, "imu", "capture", "--sil", "--seconds", "5", "--json", "--imbalance", "0")
    r = json.loads(out)
    # only the OU vibration (0.3 rad/s^2 rms, broadband): no 2 rad/s^2 line anywhere
    assert status == 0 and r["peak_rad_s2"] < 0.3


def test_capture_under_faults_counts_losses_and_still_finds_the_line(capsys):
    status, out, err = run(
        capsys,
        "imu",
        "capture",
        "--sil",
        "--seconds",
        "5",
        "--json",
        "--sil-fault",
        "disconnect:1:1.5:sa",
        "--sil-fault",
        "eio:3:3.01",
    )
    assert status == 0, err
    r = json.loads(out)
    assert r["sensors"]["sa"]["lost"] > 400 and r["sensors"]["sa"]["errors"] > 0
    # the spectrum uses the longest gap-free run: the eio may or may not cost a resync, so
    # 1.5..3.5 s (after the disconnect ends at 1.5 s): bins <= 0.67 Hz, lobe centroid
    assert 1.4 < r["spectrum_s"] < 3.5
    assert abs(r["dominant_hz"] - 25.0) < 0.3 and abs(r["peak_rad_s2"] - 2.0) < 0.15


def test_bad_arguments_exit_2_without_traceback(capsys):
    status, _, err = run(capsys, "imu", "capture", "--sil", "--seconds", "0")
    assert status == 2 and "--seconds" in err and "Traceback" not in err
    status, _, err = run(capsys, "imu", "capture", "--sil", "--sil-fault", "melt:1")
    assert status == 2 and "KIND:START:END" in err


def test_wrong_chip_exits_3_with_the_wiring_hint(capsys):
    status, _, err = run(capsys, "imu", "capture", "--sil", "--seconds", "1", "--sil-who-am-i", "0x00")
    assert status == 3 and "WHO_AM_I = 0x00" in err and "AD0" in err


def test_a_named_calibration_file_must_exist(capsys, tmp_path):
    status, _, err = run(
        capsys, "imu", "capture", "--sil", "--seconds", "1", "--calibration", str(tmp_path / "none.json")
    )
    assert status == 2 and "none.json" in err and "tvsctl imu calibrate" in err


def test_no_bus_exits_3_and_says_how_to_enable_i2c(capsys):
    status, _, err = run(capsys, "imu", "capture", "--bus", "97", "--seconds", "1")
    assert status == 3 and "/dev/i2c-97" in err and "i2c_arm" in err


def test_calibrate_sil_writes_a_file_and_refuses_a_spinning_scanner(capsys, tmp_path):
    out_file = tmp_path / "cal.json"
    status, out, err = run(capsys, "imu", "calibrate", "--sil", "--json", "--out", str(out_file))
    assert status == 0, err
    assert json.loads(out)["file"] == str(out_file)
    status, out, err = run(
        capsys, "imu", "capture", "--sil", "--seconds", "1", "--json", "--calibration", str(out_file)
    )
    assert status == 0 and json.loads(out)["calibrated"] is True
    status, _, err = run(
        capsys,
        "imu",
        "calibrate",
        "--sil",
        "--sil-moving",
        "--imbalance",
        "5",
        "--out",
        str(tmp_path / "moving.json"),
    )
    assert status == 1 and "is moving" in err and not (tmp_path / "moving.json").exists()


def test_bench_reports_cpu_and_bus_budget(capsys):
    status, out, _ = run(capsys, "imu", "bench", "--seconds", "1", "--json")
    r = json.loads(out)
    assert status == 0 and r["payload_bytes_per_s"] == 24000
    assert 0 < r["cpu_s_per_s_host"] < 0.5  # a budget, not a measurement: the Pi's is in hil/
    # the simulated bus carries what the budget computes: the twins' clocks (+2.7 %, -3.1 %)
    # and the actual poll rate differ from the budget's 1 kHz and 50 polls/s by a few %
    assert abs(r["sim_bus_bits_per_s"] / r["bus_bits_per_s"] - 1) < 0.05


def test_array_motion_from_the_plant_reaches_the_capture():
    """The lead's plant gives t, alpha_sa, omega_shaft: a 19.87 Hz line must come out as such."""
    t = np.arange(0, 6.0, 1e-4)
    f = 19.87
    alpha = 1.5 * np.sin(2 * np.pi * f * t)
    motion = ArrayMotion(t, alpha, gamma_rad=0.2, omega_shaft=np.full(t.size, 2 * np.pi * f))
    assert abs(motion.rotation_hz - f) < 1e-9
    s = ImuSettings()
    clock = ManualClock()
    bus, _ = sil_pair(s, clock, {"pl": motion, "sa": ArrayMotion(t, alpha)})
    recs = run_capture(bus, s, clock, 5.0)
    alpha_sa, fs = sa_alpha(recs["sa"], 0)
    f_peak, amp, _, _ = dominant_line(alpha_sa, fs)
    assert abs(f_peak - f) < 0.2 and abs(amp - 1.5) < 0.05  # no OU here: 3 %
