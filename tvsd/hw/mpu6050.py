"""MPU6050 driver: the only module of tvsd that speaks I2C (through smbus2).

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
"""

from __future__ import annotations

import errno as _errno
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
from smbus2 import i2c_msg

from tvsd.errors import DeviceError
from tvsd.schema import FieldError, check, option

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
SA_AXES = {"x": 0, "y": 1, "z": 2}
SG_HALF = 5  # the differentiator's half window: 11 samples


class SMBusLike(Protocol):
    """The smbus2.SMBus calls this driver makes; the simulated twin offers the same."""

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int: ...

    def write_byte_data(
        self, i2c_addr: int, register: int, value: int, force: bool | None = None
    ) -> None: ...

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]: ...

    def close(self) -> None: ...


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


def angular_acceleration(rate_rad_s: np.ndarray, fs_hz: float) -> np.ndarray:
    """d/dt of an angular rate sampled at fs_hz: the SA axis's angular acceleration (Δv).

    Savitzky-Golay derivative, cubic over 11 samples: exact for polynomials up to degree 3; at
    1 kHz its gain is within 0.1 % of the ideal jω at 25 Hz (the rotation lines), 1.4 % low at
    50 Hz, -1.7 dB at 100 Hz, and <= 0.13 of jω from 250 Hz up, where the sensor's noise is all
    that is left (a central difference keeps 0.64 at 250 Hz).
    """
    x = np.asarray(rate_rad_s, dtype=np.float64)
    n = 2 * SG_HALF + 1
    if x.size < n:
        return np.gradient(x) * fs_hz if x.size > 1 else np.zeros_like(x)
    from scipy.signal import savgol_filter  # here: the settings are loaded with every config

    return np.asarray(savgol_filter(x, n, 3, deriv=1, delta=1.0 / fs_hz, mode="interp"))


class AngularAccelerationStream:
    """angular_acceleration() for a stream of batches: same coefficients, output delayed by
    SG_HALF samples (a centred filter needs the samples after), state kept between batches.
    Reset it at a gap (a new epoch): differentiating across lost samples is meaningless."""

    def __init__(self, fs_hz: float) -> None:
        from scipy.signal import savgol_coeffs

        # convolution taps: savgol_coeffs gives them for np.convolve's orientation (use="conv")
        self._taps = savgol_coeffs(2 * SG_HALF + 1, 3, deriv=1, delta=1.0 / fs_hz, use="conv")
        self._tail = np.zeros(0)

    def reset(self) -> None:
        self._tail = np.zeros(0)

    def push(self, rate_rad_s: np.ndarray) -> np.ndarray:
        """α for the samples from SG_HALF before this batch's first one (as far as known)."""
        x = np.concatenate([self._tail, np.asarray(rate_rad_s, dtype=np.float64)])
        self._tail = x[-2 * SG_HALF :]
        if x.size < 2 * SG_HALF + 1:
            return np.zeros(0)
        return np.convolve(x, self._taps, mode="valid")


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
    """One MPU6050 on a bus. Mechanism only: the reader (imu_reader.py) decides the policy.

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
