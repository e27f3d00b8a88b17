"""The MPU6050's register map and the datasheet's facts about it: what the driver (mpu6050.py),
its settings (imu_settings.py) and the register-level twin (tvsd.sim.mpu6050) share.

Register facts are from the MPU-6000/6050 Register Map rev 4.2 and Product Specification rev 3.4.
"""

from __future__ import annotations

# Registers (Register Map rev 4.2).
SELF_TEST_X, SELF_TEST_Y, SELF_TEST_Z, SELF_TEST_A = 0x0D, 0x0E, 0x0F, 0x10
SMPLRT_DIV, CONFIG, GYRO_CONFIG, ACCEL_CONFIG = 0x19, 0x1A, 0x1B, 0x1C
FIFO_EN, INT_ENABLE, INT_STATUS = 0x23, 0x38, 0x3A
ACCEL_XOUT_H = 0x3B  # 14 bytes: accel xyz, temperature, gyro xyz
SIGNAL_PATH_RESET, USER_CTRL, PWR_MGMT_1 = 0x68, 0x6A, 0x6B
FIFO_COUNT_H, FIFO_R_W, WHO_AM_I = 0x72, 0x74, 0x75

PWR_RESET, PWR_SLEEP, CLKSEL_PLL_GYRO_X = 0x80, 0x40, 0x01
USER_FIFO_EN, USER_FIFO_RESET = 0x40, 0x04
FIFO_EN_GYRO_ACCEL = 0x78  # XG_FIFO_EN | YG_FIFO_EN | ZG_FIFO_EN | ACCEL_FIFO_EN
INT_FIFO_OFLOW = 0x10  # FIFO_OFLOW_INT / FIFO_OFLOW_EN, bit 4
SELF_TEST_BITS = 0xE0  # XA/YA/ZA_ST or XG/YG/ZG_ST, bits 7..5

FIFO_SIZE = 1024
FRAME_BYTES = 12  # accel xyz + gyro xyz, int16 big-endian
FRAMES_PER_READ = 2  # 24 bytes <= the 32-byte SMBus block limit, whole frames only
RDWR_PAIRS = 21  # block reads per combined transfer: 42 messages, the kernel's I2C_RDWR limit
RESET_S = 0.1  # a device reset takes up to 100 ms
GYRO_STARTUP_S = 0.03  # gyro start-up time, 30 ms typical
GRAVITY = 9.80665  # m/s^2, the standard g the datasheet's LSB/g refers to

# WHO_AM_I values seen on boards sold as "MPU6050"; the register map is compatible for what
# this driver uses (FIFO, ranges, DLPF). Self-test formulas are the MPU6050's only.
KNOWN_CHIPS: dict[int, str] = {
    0x68: "MPU-6050/6000",
    0x70: "MPU-6500 (sold as MPU6050)",
    0x71: "MPU-9250",
    0x72: "MPU-6050 clone (id 0x72)",
    0x73: "MPU-9255",
    0x98: "MPU-6050 clone (id 0x98)",
    0x19: "MPU-6886",
}
GENUINE_ID = 0x68

GYRO_FS_DPS = (250, 500, 1000, 2000)  # FS_SEL 0..3, 131 / 65.5 / 32.8 / 16.4 LSB per deg/s
ACCEL_FS_G = (2, 4, 8, 16)  # AFS_SEL 0..3, 16384 / 8192 / 4096 / 2048 LSB per g
# DLPF_CFG 1..6: gyro bandwidth (Hz) and delay (s); the gyro output rate is 1 kHz for all of them.
DLPF_GYRO_BW_HZ = {1: 188.0, 2: 98.0, 3: 42.0, 4: 20.0, 5: 10.0, 6: 5.0}
DLPF_DELAY_S = {1: 1.9e-3, 2: 2.8e-3, 3: 4.8e-3, 4: 8.3e-3, 5: 13.4e-3, 6: 18.6e-3}
GYRO_OUTPUT_RATE_HZ = 1000.0  # with the DLPF on (DLPF_CFG 1..6)
