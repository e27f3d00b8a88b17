"""IMU calibration at rest: gyro bias, and the accelerometer's reading of gravity.

One orientation cannot separate an accelerometer bias from the direction of gravity, so the file
keeps the mean specific force at rest (the gravity reference: tilt, and |g| as a sanity check) and
corrects only the gyro (its bias is what leaks into the angular acceleration and the integrated
rate). Refused when the sensor moves: the spread of the gyro or the drift of its mean between the
two halves of the window is over the thresholds below (10x the datasheet's noise).

File (JSON, apart from the config, written atomically):
  {"format": "tvs-imu-calibration", "version": 1, "created": ISO time,
   "sensors": {"pl": {"gyro_bias_rad_s": [3], "accel_rest_m_s2": [3], "samples": n,
                      "gyro_std_rad_s": [3], "chip": "..."}, "sa": {...}},
   "sha256": hex digest of the canonical JSON of everything else}
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from tvsd.errors import DataFileError, TvsdError

FORMAT, VERSION = "tvs-imu-calibration", 1
# Datasheet: gyro total RMS noise 0.05 deg/s (at 100 Hz bandwidth); ~0.09 deg/s at 188 Hz.
# A sensor at rest stays well under 10x that; a hand, a fan or a spinning motor does not.
# The SIL daemon's twins keep their calibration beside its data (tvsd --sil --data-dir DIR):
# their biases are not the board's, and a SIL run must never overwrite the board's file.
SIL_FILE_NAME = "imu-calibration-sil.json"
GYRO_STD_MAX_RAD_S = np.radians(0.5)
GYRO_DRIFT_MAX_RAD_S = np.radians(0.2)  # mean of first half vs second half
G_TOLERANCE = 0.1  # |accel| at rest within 10 % of g, else wrong range or not at rest
MIN_SAMPLES = 500


class CalibrationRefused(TvsdError):
    """The sensor moved (or read nonsense) during calibration; exit status 1."""


@dataclass(frozen=True)
class SensorCalibration:
    gyro_bias_rad_s: tuple[float, float, float]
    accel_rest_m_s2: tuple[float, float, float]
    samples: int
    gyro_std_rad_s: tuple[float, float, float]
    chip: str = ""


def calibrate_sensor(name: str, accel: np.ndarray, gyro: np.ndarray, chip: str = "") -> SensorCalibration:
    """Bias from samples at rest (accel m/s^2 and gyro rad/s, (n, 3) each), or refuse."""
    gyro, accel = np.asarray(gyro, float), np.asarray(accel, float)
    if len(gyro) < MIN_SAMPLES:
        raise CalibrationRefused(
            f"{name} IMU: {len(gyro)} samples at rest, need >= {MIN_SAMPLES}: capture longer"
        )
    std = gyro.std(axis=0)
    half = len(gyro) // 2
    drift = np.abs(gyro[:half].mean(axis=0) - gyro[half:].mean(axis=0))
    if np.any(std > GYRO_STD_MAX_RAD_S) or np.any(drift > GYRO_DRIFT_MAX_RAD_S):
        raise CalibrationRefused(
            f"{name} IMU is moving: gyro spread {np.degrees(std).round(3).tolist()} deg/s, drift "
            f"{np.degrees(drift).round(3).tolist()} deg/s (limits "
            f"{np.degrees(GYRO_STD_MAX_RAD_S):.2f} and {np.degrees(GYRO_DRIFT_MAX_RAD_S):.2f}): "
            "stop the motor and anything shaking the scanner, then calibrate again"
        )
    rest = accel.mean(axis=0)
    g = float(np.linalg.norm(rest))
    if abs(g / 9.80665 - 1) > G_TOLERANCE:
        raise CalibrationRefused(
            f"{name} IMU reads |a| = {g:.2f} m/s^2 at rest, not 9.81 +- 10 %: check "
            "imu.accel_fs_g and that the sensor is at rest"
        )
    return SensorCalibration(
        tuple(gyro.mean(axis=0).tolist()),
        tuple(rest.tolist()),
        len(gyro),
        tuple(std.tolist()),
        chip,
    )


def _digest(body: dict[str, object]) -> str:
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


def save(path: Path, sensors: dict[str, SensorCalibration]) -> None:
    body: dict[str, object] = {
        "format": FORMAT,
        "version": VERSION,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "sensors": {
            name: {
                "gyro_bias_rad_s": list(c.gyro_bias_rad_s),
                "accel_rest_m_s2": list(c.accel_rest_m_s2),
                "samples": c.samples,
                "gyro_std_rad_s": list(c.gyro_std_rad_s),
                "chip": c.chip,
            }
            for name, c in sensors.items()
        },
    }
    text = json.dumps({**body, "sha256": _digest(body)}, indent=2, sort_keys=True) + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as f:  # write then rename: a crash never leaves half a file
        f.write(text)
    os.replace(tmp, path)


def load(path: Path) -> dict[str, SensorCalibration]:
    """Read and verify a calibration file; DataFileError (exit 2) says what is wrong."""
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError as exc:
        raise DataFileError(
            f"{path}: no IMU calibration file; run `tvsctl imu calibrate` with the scanner at rest"
        ) from exc
    except (OSError, ValueError) as exc:
        raise DataFileError(f"{path}: unreadable IMU calibration ({exc})") from exc
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise DataFileError(f"{path}: not an IMU calibration file (format != {FORMAT!r})")
    if data.get("version") != VERSION:
        raise DataFileError(
            f"{path}: calibration version {data.get('version')!r}, this tvsd reads {VERSION}: calibrate again"
        )
    digest = data.pop("sha256", None)
    if digest != _digest(data):
        raise DataFileError(f"{path}: checksum mismatch (edited or damaged): calibrate again")
    try:
        return {
            name: SensorCalibration(
                tuple(float(v) for v in c["gyro_bias_rad_s"]),  # type: ignore[arg-type]
                tuple(float(v) for v in c["accel_rest_m_s2"]),  # type: ignore[arg-type]
                int(c["samples"]),
                tuple(float(v) for v in c["gyro_std_rad_s"]),  # type: ignore[arg-type]
                str(c.get("chip", "")),
            )
            for name, c in data["sensors"].items()
        }
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise DataFileError(f"{path}: calibration entry malformed ({exc!r})") from exc


def load_or_none(path: Path) -> dict[str, SensorCalibration] | None:
    """At start: None (uncalibrated, a warning) if absent; a damaged file is still an error."""
    return load(path) if Path(path).exists() else None
