"""The `imu:` config section (ImuSettings: the two MPU6050s and how they are read) and what it
means for the data: the sensor axis along the SA shaft, raw counts to SI units."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvsd.hw.mpu6050_registers import (
    ACCEL_FS_G,
    DLPF_GYRO_BW_HZ,
    GRAVITY,
    GYRO_FS_DPS,
    GYRO_OUTPUT_RATE_HZ,
)
from tvsd.schema import FieldError, check, option

SA_AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True, kw_only=True)
class ImuSettings:
    """The two MPU6050s: the `imu:` config section, and the driver's settings.

    Each key has its rule (`option`); `__post_init__` adds the chip's own (rates the sample-rate
    divider can make, ranges the chip has, the DLPF against the rate), so the rules hold however
    the settings are made: from the config file (errors at the key's line), the command line, a test.
    """

    bus: int = option(1, doc="I2C bus number (/dev/i2c-N)", ge=0)
    address_pl: int = option(0x68, doc="PL sensor address (AD0 low)", ge=0, le=0x7F)
    address_sa: int = option(0x69, doc="SA sensor address (AD0 high)", ge=0, le=0x7F)
    sample_rate_hz: float = option(1000.0, doc="FIFO rate (MODEL-NOTES §4: ≥ 1 kHz)", unit="Hz", gt=0)
    # 188 Hz: passes the 15-25 Hz lines and structural modes to ~150 Hz
    dlpf_cfg: int = option(1, doc="digital low-pass setting 1..6 (1: 188 Hz)", ge=0, le=7)
    # finest LSB; vibration rates here are a few deg/s
    gyro_fs_dps: int = option(250, doc="gyro full scale", unit="°/s", gt=0)
    # real MPU6050 records on motors clip at +-2 g (data/real): headroom
    accel_fs_g: int = option(4, doc="accelerometer full scale", unit="g", gt=0)
    sa_axis: str = option("x", doc="sensor axis along the SA shaft", choices=tuple(SA_AXES))
    calibration_file: Path = option(Path("/var/lib/tvsd/imu-calibration.json"), doc="bias calibration file")
    # 20 frames per poll at 1 kHz; the FIFO holds 85 (85 ms), so 50 ms leaves margin
    poll_interval_s: float = option(0.02, doc="FIFO poll period", unit="s", ge=0.001, le=0.05)
    calibrate_max_s: float = option(
        60.0, doc="a bias calibration at rest takes at most this long", unit="s", gt=0, le=3600
    )
    lost_margin_s: float = option(
        0.1, doc="a sensor is lost after 5 poll periods and this long without a sample", unit="s", gt=0
    )

    def __post_init__(self) -> None:
        check(self)
        for key in ("address_pl", "address_sa"):
            if getattr(self, key) not in (0x68, 0x69):
                got = getattr(self, key)
                raise FieldError(key, f"must be 0x68 (AD0 low) or 0x69 (AD0 high), got {got:#x}")
        if self.address_pl == self.address_sa:
            raise FieldError("address_sa", "pl and sa share one address; tie AD0 high on one")
        if self.dlpf_cfg not in DLPF_GYRO_BW_HZ:
            raise FieldError(
                "dlpf_cfg",
                f"must be 1..6, got {self.dlpf_cfg!r}: 0 and 7 switch the DLPF off "
                "(8 kHz gyro, 1 kHz accelerometer, no anti-alias filter)",
            )
        rate = self.sample_rate_hz
        divider = GYRO_OUTPUT_RATE_HZ / rate - 1.0
        if abs(divider - round(divider)) > 1e-3 or not 0 <= round(divider) < 256:
            raise FieldError(
                "sample_rate_hz",
                "must be 1000/(1+d) Hz for an integer d in 0..255 "
                f"(1000, 500, 333.33..., 250 ...; 1000 is the scanner's rate), got {rate!r}",
            )
        bandwidth = DLPF_GYRO_BW_HZ[self.dlpf_cfg]
        if rate < 2.5 * bandwidth:  # Nyquist with margin for the DLPF's roll-off
            raise FieldError(
                "sample_rate_hz",
                f"{rate:g} Hz aliases the DLPF's {bandwidth:g} Hz band: raise the rate to >= "
                f"{2.5 * bandwidth:g} Hz or raise imu.dlpf_cfg",
            )
        if self.gyro_fs_dps not in GYRO_FS_DPS:
            raise FieldError("gyro_fs_dps", f"must be one of {GYRO_FS_DPS}, got {self.gyro_fs_dps!r}")
        if self.accel_fs_g not in ACCEL_FS_G:
            raise FieldError("accel_fs_g", f"must be one of {ACCEL_FS_G}, got {self.accel_fs_g!r}")

    @property
    def addresses(self) -> dict[str, int]:
        """The I2C address of each sensor, by name ("pl", "sa")."""
        return {"pl": self.address_pl, "sa": self.address_sa}

    @property
    def smplrt_div(self) -> int:
        return round(GYRO_OUTPUT_RATE_HZ / self.sample_rate_hz) - 1

    @property
    def gyro_lsb_to_rad_s(self) -> float:
        return self.gyro_fs_dps / 32768.0 * np.pi / 180.0

    @property
    def accel_lsb_to_m_s2(self) -> float:
        return self.accel_fs_g / 32768.0 * GRAVITY


def to_si(raw: np.ndarray, settings: ImuSettings) -> tuple[np.ndarray, np.ndarray]:
    """(n, 6) int16 frames -> accel (n, 3) m/s^2 and gyro (n, 3) rad/s."""
    raw = np.asarray(raw, dtype=np.float64).reshape(-1, 6)
    return raw[:, :3] * settings.accel_lsb_to_m_s2, raw[:, 3:] * settings.gyro_lsb_to_rad_s
