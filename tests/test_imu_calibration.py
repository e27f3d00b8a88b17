"""Calibration at rest through the driver and reader on the twins; the file's integrity checks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tvsd.cli.imu import run_capture
from tvsd.errors import DataFileError
from tvsd.hw import imu_calibration as cal
from tvsd.hw.imu_clock import ManualClock
from tvsd.hw.imu_settings import ImuSettings
from tvsd.sim.imu_motion import SyntheticParams, synthetic_pair
from tvsd.sim.mpu6050 import GYRO_NOISE_DPS_RTHZ, sil_pair

S = ImuSettings()


def capture(seconds: float = 2.0, **motion: float):
    clock = ManualClock()
    params = SyntheticParams(**motion)
    bus, devs = sil_pair(S, clock, synthetic_pair(params))
    return run_capture(bus, S, clock, seconds), devs


def test_bias_at_rest_matches_the_twins_bias():
    recs, devs = capture(rps=0, imbalance_rad_s2=0, vibration_std_rad_s2=0)
    for name, rec in recs.items():
        c = cal.calibrate_sensor(name, rec.accel, rec.gyro)
        # The mean of n samples of the twin's white rate noise (GYRO_NOISE_DPS_RTHZ over the
        # ~1 kHz Nyquist band: 0.11 deg/s a sample), taken as correlated over 2 samples as a real
        # DLPF would (the 1/131 deg/s LSB is dithered by that noise): σ = 6.5e-5 rad/s at
        # n = 1800. Bound: 5σ on each of the 6 axes (a 1e-4 bound was 1.5σ and failed one axis
        # by chance, 1.05e-4, in a CI run).
        per_sample = np.deg2rad(GYRO_NOISE_DPS_RTHZ) * np.sqrt(1000.0 / 2.0)
        sigma = per_sample * np.sqrt(2.0 / len(rec.gyro))
        np.testing.assert_allclose(c.gyro_bias_rad_s, devs[name].gyro_bias, atol=5 * sigma)
        assert abs(np.linalg.norm(c.accel_rest_m_s2) - 9.80665) < 0.6  # twin bias <= 0.3/axis


def test_a_moving_sensor_is_refused_with_the_numbers():
    recs, _ = capture(rps=25, imbalance_rad_s2=5.0)  # 5 rad/s^2 at 25 Hz: 1.8 deg/s rate swing
    with pytest.raises(cal.CalibrationRefused, match=r"sa IMU is moving: gyro spread") as exc:
        cal.calibrate_sensor("sa", recs["sa"].accel, recs["sa"].gyro)
    assert exc.value.exit_status == 1


def test_too_few_samples_or_no_gravity_are_refused():
    with pytest.raises(cal.CalibrationRefused, match="need >= 500"):
        cal.calibrate_sensor("pl", np.zeros((10, 3)), np.zeros((10, 3)))
    with pytest.raises(cal.CalibrationRefused, match=r"\|a\| = 0.00"):
        cal.calibrate_sensor("pl", np.zeros((600, 3)), np.zeros((600, 3)))


def _good(tmp_path):
    c = cal.SensorCalibration((0.01, -0.02, 0.003), (0.1, 0.2, 9.8), 2000, (1e-3,) * 3, "x")
    path = tmp_path / "cal.json"
    cal.save(path, {"pl": c, "sa": c})
    return path, c


def test_save_and_load_round_trip(tmp_path):
    path, c = _good(tmp_path)
    assert cal.load(path) == {"pl": c, "sa": c}
    assert cal.load_or_none(tmp_path / "absent.json") is None


def test_an_edited_file_fails_its_checksum(tmp_path):
    path, _ = _good(tmp_path)
    data = json.loads(path.read_text())
    data["sensors"]["pl"]["gyro_bias_rad_s"][0] = 0.5
    path.write_text(json.dumps(data))
    with pytest.raises(DataFileError, match="checksum mismatch"):
        cal.load(path)


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda d: d.update(version=2), "version 2"),
        (lambda d: d.update(format="other"), "not an IMU calibration"),
    ],
)
def test_wrong_version_or_format_is_a_clear_error(tmp_path, edit, words):
    path, _ = _good(tmp_path)
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.raises(DataFileError, match=words):
        cal.load(path)


def test_missing_and_garbage_files(tmp_path):
    with pytest.raises(DataFileError, match="tvsctl imu calibrate"):
        cal.load(tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(DataFileError, match="unreadable"):
        cal.load(tmp_path / "bad.json")
