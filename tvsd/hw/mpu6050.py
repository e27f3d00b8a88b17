"""MPU6050 driver: one sensor's transfers through smbus2 (both sensors' shared poll: tvsd.hw.imu_joint).

Register facts are from the MPU-6000/6050 Register Map rev 4.2 and Product Specification rev 3.4.

Transfers: a sensor polled alone drains its FIFO with SMBus block reads of whole frames, two
12-byte frames (accel xyz + gyro xyz, big-endian int16) per block read (24 of the 32 bytes an
SMBus block read allows), up to 21 of them in one ``i2c_rdwr`` where the adapter has it. A
whole-frame read never leaves half a frame in the FIFO, and works on every Linux adapter
(including SMBus-only ones, which reject ``i2c_rdwr``). Its cost: 3 header bytes per 24 payload
bytes — two sensors at 1 kHz use ~63 % of a 400 kHz bus. Both sensors polled together
(tvsd.hw.imu_joint, the reader's normal case on an adapter with ``i2c_rdwr``) read each FIFO in
one burst: ~55 % (see :func:`bus_budget`). A 100 kHz bus is too slow either way and
hil/README.md says to raise it.

Registers and chip facts: mpu6050_registers.py; the settings: imu_settings.py.
"""

from __future__ import annotations

import errno as _errno
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from smbus2 import i2c_msg

from tvsd.errors import DeviceError
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050_registers import (
    ACCEL_CONFIG,
    ACCEL_FS_G,
    ACCEL_XOUT_H,
    CLKSEL_PLL_GYRO_X,
    CONFIG,
    FIFO_COUNT_H,
    FIFO_EN,
    FIFO_EN_GYRO_ACCEL,
    FIFO_R_W,
    FRAME_BYTES,
    FRAMES_PER_READ,
    GENUINE_ID,
    GYRO_CONFIG,
    GYRO_FS_DPS,
    GYRO_STARTUP_S,
    INT_ENABLE,
    INT_FIFO_OFLOW,
    INT_STATUS,
    KNOWN_CHIPS,
    PWR_MGMT_1,
    PWR_RESET,
    PWR_SLEEP,
    RDWR_PAIRS,
    RESET_S,
    SELF_TEST_A,
    SELF_TEST_BITS,
    SELF_TEST_X,
    SELF_TEST_Y,
    SELF_TEST_Z,
    SIGNAL_PATH_RESET,
    SMPLRT_DIV,
    USER_CTRL,
    USER_FIFO_EN,
    USER_FIFO_RESET,
    WHO_AM_I,
)


class SMBusLike(Protocol):
    """The smbus2.SMBus calls this driver makes; the twins' bus (tvsd.sim.i2c_bus) and the remote
    one (tvsd.hw.i2c_remote) offer the same."""

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int: ...

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None: ...

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]: ...

    def close(self) -> None: ...


def bus_budget(
    settings: ImuSettings, sensors: int = 2, bus_hz: float = 400e3, burst: bool = True
) -> dict[str, float]:
    """Payload bytes/s against the bus capacity, for the polling scheme of this driver.

    Bits per transaction: start + address + register + restart + address + data bytes, 9 bits per
    byte (ACK included) and ~2 bit times for start/stop. `burst`: each poll reads a sensor's
    frames in one burst (tvsd.hw.imu_joint, a bus with i2c_rdwr); else in 2-frame block reads.
    """
    polls = 1.0 / settings.poll_interval_s
    payload_bytes = settings.sample_rate_hz * FRAME_BYTES
    if burst:
        bits_per_frame = 9.0 * FRAME_BYTES
        poll_bits = polls * ((27 + 9 * 2 + 2) + (27 + 2) + (27 + 9 * 1 + 2))  # count, burst, INT_STATUS
    else:
        bits_per_frame = (27 + 9 * FRAMES_PER_READ * FRAME_BYTES + 2) / FRAMES_PER_READ
        poll_bits = polls * ((27 + 9 * 2 + 2) + (27 + 9 * 1 + 2))  # FIFO_COUNT + INT_STATUS
    used = sensors * (settings.sample_rate_hz * bits_per_frame + poll_bits)
    max_rate = (bus_hz / sensors - poll_bits) / bits_per_frame
    return {
        "payload_bytes_per_s": sensors * payload_bytes,
        "bus_bits_per_s": used,
        "bus_capacity_bits_per_s": bus_hz,
        "utilization": used / bus_hz,
        "payload_efficiency": sensors * payload_bytes * 8 / used,
        "max_rate_hz_per_sensor": max_rate,
    }


@dataclass(frozen=True)
class SelfTestResult:
    """Datasheet self-test: response change from factory trim per axis, pass within +-14 %."""

    accel_change: tuple[float, float, float]
    gyro_change: tuple[float, float, float]

    @property
    def passed(self) -> bool:
        return all(abs(c) <= 0.14 for c in (*self.accel_change, *self.gyro_change))


class Mpu6050:
    """One MPU6050 on a bus. Mechanism only: the policy is the sensor reader's (imu_sensor_reader.py).

    Every bus failure is raised as DeviceError naming bus, address and sensor, with the kernel's
    errno kept in ``.errno`` and the OSError chained.
    """

    def __init__(
        self,
        bus: SMBusLike,
        name: str,
        settings: ImuSettings,
        sleep: Callable[[float], None],
    ) -> None:
        self.bus = bus
        self.name = name
        self.settings = settings
        self.address = settings.addresses[name]
        self.sleep = sleep
        self.chip_id: int | None = None

    def _where(self) -> str:
        return f"I2C bus {self.settings.bus} address 0x{self.address:02x} ({self.name} IMU)"

    def _fail(self, what: str, exc: OSError) -> DeviceError:
        hint = ""
        if exc.errno in (_errno.ENXIO, _errno.EREMOTEIO):
            hint = ": no ACK; check power, SDA/SCL wiring and the AD0 address pin"
        elif exc.errno == _errno.ETIMEDOUT:
            hint = ": bus timed out; a sensor may be holding SDA low (power-cycle it)"
        err = DeviceError(f"{self._where()}: {what} failed ({exc.strerror or exc}){hint}")
        err.errno = exc.errno
        return err

    def _read(self, register: int, what: str) -> int:
        try:
            return self.bus.read_byte_data(self.address, register)
        except OSError as exc:
            raise self._fail(f"read of {what}", exc) from exc

    def _write(self, register: int, value: int, what: str) -> None:
        try:
            self.bus.write_byte_data(self.address, register, value)
        except OSError as exc:
            raise self._fail(f"write of {what}", exc) from exc

    def _block(self, register: int, length: int, what: str) -> bytes:
        try:
            data = self.bus.read_i2c_block_data(self.address, register, length)
        except OSError as exc:
            raise self._fail(f"read of {what}", exc) from exc
        if len(data) != length:
            raise DeviceError(f"{self._where()}: {what}: {len(data)} bytes for {length}")
        return bytes(data)

    def probe(self) -> str:
        """Read WHO_AM_I; return the chip's name or raise DeviceError saying what to check."""
        chip = self._read(WHO_AM_I, "WHO_AM_I")
        if chip not in KNOWN_CHIPS:
            raise DeviceError(
                f"{self._where()}: WHO_AM_I = 0x{chip:02x}, not an MPU6050 (expected 0x68 or a "
                f"known clone: {', '.join(f'0x{k:02x}' for k in KNOWN_CHIPS)}). Something else "
                "answers at this address, or the wiring is faulty: check SDA/SCL, power, and that "
                f"AD0 is {'low' if self.address == 0x68 else 'high'} on this board"
            )
        self.chip_id = chip
        return KNOWN_CHIPS[chip]

    def reset(self) -> None:
        """Device reset: registers to defaults, asleep. Takes up to 100 ms (RESET_S)."""
        self._write(PWR_MGMT_1, PWR_RESET, "PWR_MGMT_1 (reset)")

    def configure(self) -> None:
        """Wake on the gyro PLL, set DLPF, rate, ranges, and start the FIFO (after reset())."""
        s = self.settings
        self._write(SIGNAL_PATH_RESET, 0x07, "SIGNAL_PATH_RESET")
        self._write(PWR_MGMT_1, CLKSEL_PLL_GYRO_X, "PWR_MGMT_1 (wake, PLL)")
        regs = {
            CONFIG: (s.dlpf_cfg, "CONFIG"),
            SMPLRT_DIV: (s.smplrt_div, "SMPLRT_DIV"),
            GYRO_CONFIG: (GYRO_FS_DPS.index(s.gyro_fs_dps) << 3, "GYRO_CONFIG"),
            ACCEL_CONFIG: (ACCEL_FS_G.index(s.accel_fs_g) << 3, "ACCEL_CONFIG"),
            INT_ENABLE: (INT_FIFO_OFLOW, "INT_ENABLE"),
        }
        for reg, (value, what) in regs.items():
            self._write(reg, value, what)
        for reg, (value, what) in regs.items():  # a clone that ignores writes is caught here
            got = self._read(reg, what)
            if got != value:
                raise DeviceError(
                    f"{self._where()}: {what} reads 0x{got:02x} after writing 0x{value:02x}; "
                    "the chip does not keep its configuration (clone or power trouble)"
                )
        self.reset_fifo()

    def start(self) -> str:
        """Blocking bring-up: probe, reset, configure, and a clean FIFO once the gyro runs."""
        chip = self.probe()
        self.reset()
        self.sleep(RESET_S)
        self.configure()
        self.sleep(GYRO_STARTUP_S)
        self.reset_fifo()
        return chip

    def reset_fifo(self, status_first: bool = False) -> bool:
        """Empty the FIFO and restart it aligned on a frame; clears a pending overflow flag.
        With `status_first`, INT_STATUS is read before the reset too: returns whether the FIFO
        had overflowed (else False). A bus with i2c_rdwr does it all in one combined transfer
        (one round trip, not five: a reader that fell behind resyncs without falling further)."""
        writes = [
            (FIFO_EN, 0, "FIFO_EN"),
            (USER_CTRL, USER_FIFO_RESET, "USER_CTRL (FIFO reset)"),
            (FIFO_EN, FIFO_EN_GYRO_ACCEL, "FIFO_EN"),
            (USER_CTRL, USER_FIFO_EN, "USER_CTRL (FIFO on)"),
        ]
        rdwr = getattr(self.bus, "i2c_rdwr", None)
        if rdwr is None:
            flag = self.read_overflow() if status_first else False
            for register, value, what in writes:
                self._write(register, value, what)
            self.read_overflow()
            return flag
        before, after = i2c_msg.read(self.address, 1), i2c_msg.read(self.address, 1)
        msgs = [i2c_msg.write(self.address, [INT_STATUS]), before] if status_first else []
        msgs += [i2c_msg.write(self.address, [register, value]) for register, value, _ in writes]
        msgs += [i2c_msg.write(self.address, [INT_STATUS]), after]
        try:
            rdwr(*msgs)
        except OSError as exc:
            raise self._fail("write of FIFO_EN/USER_CTRL (combined FIFO reset)", exc) from exc
        return status_first and bool(bytes(before)[0] & INT_FIFO_OFLOW)

    def is_running(self) -> bool:
        """False after a power cycle or reset behind our back (asleep or FIFO off)."""
        power = self._read(PWR_MGMT_1, "PWR_MGMT_1")
        user = self._read(USER_CTRL, "USER_CTRL")
        return not power & PWR_SLEEP and bool(user & USER_FIFO_EN)

    def read_overflow(self) -> bool:
        """Read INT_STATUS (which clears it); True if the FIFO overflowed since the last read."""
        return bool(self._read(INT_STATUS, "INT_STATUS") & INT_FIFO_OFLOW)

    def fifo_count(self) -> int:
        """Bytes in the FIFO."""
        high, low = self._block(FIFO_COUNT_H, 2, "FIFO_COUNT")
        return (high << 8) | low

    def read_frames(self, frames: int, out: list[np.ndarray]) -> None:
        """Read `frames` whole frames, appending (k, 6) int16 arrays to `out` as they arrive.

        Frames already read stay in `out` if a later transfer fails (they are intact: every
        transfer is whole frames), so the caller loses nothing it was given. A bus with i2c_rdwr
        (smbus2's, the twins', tvsd.hw.i2c_remote's) gets up to RDWR_PAIRS block reads in one
        combined transfer: one syscall, one round trip; the frames of a failed one are lost.
        """
        rdwr = getattr(self.bus, "i2c_rdwr", None)
        while frames > 0:
            if rdwr is not None and frames > FRAMES_PER_READ:
                frames -= self._read_frames_combined(rdwr, frames, out)
                continue
            n = min(frames, FRAMES_PER_READ)
            data = self._block(FIFO_R_W, n * FRAME_BYTES, "FIFO_R_W")
            out.append(np.frombuffer(data, dtype=">i2").reshape(n, 6).astype(np.int16))
            frames -= n

    def read_frames_then_overflow(self, frames: int, out: list[np.ndarray]) -> bool:
        """read_frames, then read_overflow; with i2c_rdwr the INT_STATUS read rides in the last
        FIFO transfer (the same transactions, in the same order, one ioctl fewer: one round trip
        and one GIL retake fewer per poll). If that transfer fails, its frames and the status
        are lost together (DeviceError, as read_frames)."""
        rdwr = getattr(self.bus, "i2c_rdwr", None)
        if rdwr is None or frames <= 0:
            self.read_frames(frames, out)
            return self.read_overflow()
        while frames > (RDWR_PAIRS - 1) * FRAMES_PER_READ:  # more than the last one holds
            frames -= self._read_frames_combined(rdwr, frames, out)
        status = bytearray(1)
        self._read_frames_combined(rdwr, frames, out, status=status)
        return bool(status[0] & INT_FIFO_OFLOW)

    def _read_frames_combined(
        self,
        rdwr: Callable[..., None],
        frames: int,
        out: list[np.ndarray],
        status: bytearray | None = None,
    ) -> int:
        """Up to RDWR_PAIRS block reads of the FIFO in one combined transfer (one I2C_RDWR
        ioctl, one round trip to a bus in another process): the same transactions on the wire
        as one read_i2c_block_data each; with `status`, INT_STATUS read after them into it
        (one pair fewer for frames). Returns the frames read."""
        pairs = RDWR_PAIRS - (status is not None)
        sizes: list[int] = []
        while frames > 0 and len(sizes) < pairs:
            sizes.append(min(frames, FRAMES_PER_READ))
            frames -= sizes[-1]
        reads = [i2c_msg.read(self.address, n * FRAME_BYTES) for n in sizes]
        msgs = [m for r in reads for m in (i2c_msg.write(self.address, [FIFO_R_W]), r)]
        status_read = i2c_msg.read(self.address, 1)
        if status is not None:
            msgs += [i2c_msg.write(self.address, [INT_STATUS]), status_read]
        try:
            rdwr(*msgs)
        except OSError as exc:
            err = self._fail("combined read of FIFO_R_W", exc)
            if len(msgs) > 2 and err.errno in (_errno.ENXIO, _errno.EREMOTEIO):
                # a later message's NACK: the earlier ones may have popped whole frames, which
                # the kernel does not hand back; the reader must realign (a NACK means "nothing
                # moved" only for a single transfer)
                err.errno = _errno.EIO
            raise err from exc
        if reads:
            data = b"".join(bytes(r) for r in reads)
            out.append(np.frombuffer(data, dtype=">i2").reshape(-1, 6).astype(np.int16))
        if status is not None:
            status[0] = bytes(status_read)[0]
        return sum(sizes)

    def read_latest(self) -> np.ndarray:
        """The data registers (latest sample, not the FIFO): int16 [ax, ay, az, gx, gy, gz]."""
        raw = np.frombuffer(self._block(ACCEL_XOUT_H, 14, "ACCEL_XOUT..GYRO_ZOUT"), dtype=">i2")
        return np.concatenate([raw[:3], raw[4:]]).astype(np.int16)

    def self_test(self, samples: int = 50) -> SelfTestResult:
        """Datasheet self-test at +-250 deg/s and +-8 g; leaves the sensor to be reconfigured.

        Response = mean output with self-test on minus off; compared with the factory trim from
        SELF_TEST_X..A (Register Map 4.1). Genuine MPU6050 (WHO_AM_I 0x68) only.
        """
        if self.chip_id is None:
            self.probe()
        if self.chip_id != GENUINE_ID:
            raise DeviceError(
                f"{self._where()}: self-test formulas are the MPU6050's; this chip is "
                f"{KNOWN_CHIPS.get(self.chip_id or 0, 'unknown')}"
            )
        st = [self._read(reg, "SELF_TEST") for reg in (SELF_TEST_X, SELF_TEST_Y, SELF_TEST_Z)]
        st_a = self._read(SELF_TEST_A, "SELF_TEST_A")
        g_test = [v & 0x1F for v in st]
        a_test = [((v >> 3) & 0x1C) | ((st_a >> (4 - 2 * i)) & 0x03) for i, v in enumerate(st)]
        means = []
        for bits in (0, SELF_TEST_BITS):
            self._write(GYRO_CONFIG, bits, "GYRO_CONFIG (self-test)")
            self._write(ACCEL_CONFIG, bits | (2 << 3), "ACCEL_CONFIG (self-test)")
            self.sleep(0.05)  # let the outputs settle through the DLPF
            acc = []
            for _ in range(samples):
                acc.append(self.read_latest().astype(np.float64))
                self.sleep(1.0 / self.settings.sample_rate_hz)
            means.append(np.mean(acc, axis=0))
        response = means[1] - means[0]
        accel_ft = [4096 * 0.34 * (0.92 / 0.34) ** ((t - 1) / 30) if t else 0.0 for t in a_test]
        gyro_ft = [
            sign * 25 * 131 * 1.046 ** (t - 1) if t else 0.0
            for sign, t in zip((1, -1, 1), g_test, strict=True)
        ]

        def change(measured: float, trim: float) -> float:
            return (measured - trim) / trim if trim else float("inf")

        accel = tuple(change(response[i], accel_ft[i]) for i in range(3))
        gyro = tuple(change(response[3 + i], gyro_ft[i]) for i in range(3))
        return SelfTestResult(accel, gyro)  # type: ignore[arg-type]
