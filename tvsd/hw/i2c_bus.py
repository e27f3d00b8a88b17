"""Opening the real I2C bus (smbus2), with the advice a user needs when it is not there.

The daemon's IMU service and `tvsctl imu` both open the bus here; the simulated bus
(tvsd.sim.i2c_bus.SimI2CBus) stands behind the same SMBus-like interface.
"""

from __future__ import annotations

from tvsd.errors import DeviceError
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050 import SMBusLike


def open_bus(settings: ImuSettings) -> SMBusLike:
    """The real bus, or DeviceError saying how to get one."""
    try:
        import smbus2

        return smbus2.SMBus(settings.bus)
    except (OSError, ImportError) as exc:
        raise DeviceError(
            f"cannot open /dev/i2c-{settings.bus} ({exc}): enable I2C (raspi-config, or "
            "dtparam=i2c_arm=on in config.txt), check imu.bus, and that this user is in group "
            "i2c; or use --sil for the simulated sensors"
        ) from exc
