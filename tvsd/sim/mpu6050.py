"""Simulated MPU6050s: the driver's twin at the register level.

Each SimMpu6050 keeps a register map and a 1024-byte FIFO filled, on every access, with the
samples its own clock (nominal rate times 1 + rate_error: these oscillators run a few % off)
produced since the last access. The time comes from a Clock: a ManualClock runs faster than real
time (and the bus, tvsd.sim.i2c_bus.SimI2CBus, charges each transaction's bit time to it), a
MonotonicClock runs in real time. sil_pair puts the scanner's two on one simulated bus.

Signals: "motion" samples a MotionSource through a DLPF model (`dlpf_sos`: the datasheet's
bandwidth and delay), adds the datasheet's noise and a bias, and quantizes to int16 at the
configured range (clipping like the chip). "counter" puts a running sample number and a check
word in each frame, so tests can see exactly which samples the driver delivered, lost, or
misaligned.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np
from scipy.signal import butter, group_delay, sos2tf, sosfilt_zi

from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.imu_clock import Clock
from tvsd.hw.imu_settings import ImuSettings
from tvsd.sim.i2c_bus import SimI2CBus
from tvsd.sim.imu_motion import MotionSource
from tvsd.sim.twin_kernels import dlpf_counts, warm

GYRO_NOISE_DPS_RTHZ = 0.005  # rate noise spectral density (datasheet)
ACCEL_NOISE_G_RTHZ = 400e-6  # power spectral density (datasheet)
# Self-test codes of this simulated part; the response equals the factory trim times 1 + error.
ST_GYRO_CODES = (14, 17, 12)
ST_ACCEL_CODES = (16, 15, 18)


def dlpf_sos(dlpf_cfg: int, rate_hz: float) -> np.ndarray:
    """The DLPF model: a 2nd-order Butterworth at the register's bandwidth, then a first-order
    allpass (Thiran) fractional delay and whole-sample delays, so that the delay at low
    frequencies is the datasheet's (DLPF_DELAY_S, which the daemon subtracts): the Butterworth
    alone delays 1.2 ms at 188 Hz against the chip's 1.9 ms, and a 0.7 ms error puts the SA
    sensor's acceleration that much off the pulses it compensates. The allpass leaves the
    magnitude, which the datasheet gives only as the bandwidth, untouched. From DLPF_CFG 3 on,
    the Butterworth alone already delays more than the datasheet says (5.3 vs 4.8 ms at 42 Hz):
    left as it is, since no causal filter takes delay away."""
    bw = reg.DLPF_GYRO_BW_HZ.get(dlpf_cfg, 256.0)
    sos = butter(2, min(bw, 0.45 * rate_hz), fs=rate_hz, output="sos")
    want = reg.DLPF_DELAY_S.get(dlpf_cfg)
    if want is None:
        return sos
    b, a = sos2tf(sos)
    have = float(group_delay((b, a), w=[1e-3], fs=rate_hz)[1][0])  # samples, near DC
    extra = want * rate_hz - have
    whole = max(0, int(np.floor(extra - 0.5)))
    frac = extra - whole  # in [0.5, 1.5): the Thiran allpass is well damped there
    sections = [sos]
    if frac > 0:
        c = (1.0 - frac) / (1.0 + frac)
        sections.append(np.array([[c, 1.0, 0.0, 1.0, c, 0.0]]))
    sections += [np.array([[0.0, 1.0, 0.0, 1.0, 0.0, 0.0]])] * whole
    return np.vstack(sections)


def encode_counter(n: np.ndarray) -> np.ndarray:
    """Frames carrying sample numbers n: [n low 15 bits, n high bits, check, check ^ 0x1111 ...]."""
    lo, hi = n & 0x7FFF, (n >> 15) & 0x7FFF
    check = lo ^ hi ^ 0x2A5A
    return np.stack([lo, hi, check, check ^ 0x1111, check ^ 0x2222, check ^ 0x3333], axis=1)


def decode_counter(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sample numbers, frame is intact) from int16 frames made by encode_counter."""
    raw = np.asarray(raw, dtype=np.int64)
    lo, hi, check = raw[:, 0], raw[:, 1], raw[:, 2]
    ok = (check == lo ^ hi ^ 0x2A5A) & (raw[:, 3] == check ^ 0x1111) & (lo >= 0) & (hi >= 0)
    ok &= (raw[:, 4] == check ^ 0x2222) & (raw[:, 5] == check ^ 0x3333)
    return lo | (hi << 15), ok


class SimMpu6050:
    """One simulated sensor. `produced` counts every frame written to its FIFO (ground truth)."""

    def __init__(
        self,
        motion: MotionSource | None,
        clock: Clock,
        who_am_i: int = 0x68,
        rate_error: float = 0.027,
        signal: str = "motion",
        seed: int = 0,
        st_error: float = 0.03,
    ) -> None:
        if signal not in ("motion", "counter") or (signal == "motion" and motion is None):
            raise ValueError("signal must be 'counter', or 'motion' with a MotionSource")
        self.motion, self.clock, self.signal = motion, clock, signal
        if signal == "motion":
            warm()  # its kernels compiled before the first poll, not in it
        self.who_am_i, self.rate_error, self.st_error = who_am_i, rate_error, st_error
        rng = np.random.default_rng(seed)
        self._rng = rng
        self.gyro_bias = rng.uniform(-0.02, 0.02, 3)  # rad/s (about 1 deg/s)
        self.accel_bias = rng.uniform(-0.3, 0.3, 3)  # m/s^2 (about 30 mg)
        self.produced = 0  # frames written into the FIFO, including those later dropped
        self.sample_number = 0  # every sample taken, FIFO on or off (the counter signal)
        # CPU spent generating samples, on the calling thread's clock (to separate it in
        # benchmarks; process time would add whatever the process's other threads ran meanwhile),
        # and how many generations (each has a fixed cost: the motion source, the DLPF call)
        self.cpu_s = 0.0
        self.generations = 0
        self.record_times = False  # for tests: keep the true time of every sample taken
        self.sample_times: list[np.ndarray] = []  # (by sample number) when record_times
        self.hard_reset()

    def hard_reset(self) -> None:
        """Power-on state: asleep, registers at their defaults, FIFO empty."""
        self.regs = bytearray(128)
        self.regs[reg.PWR_MGMT_1] = reg.PWR_SLEEP
        self.regs[reg.WHO_AM_I] = self.who_am_i
        a, g = ST_ACCEL_CODES, ST_GYRO_CODES
        for i, r in enumerate((reg.SELF_TEST_X, reg.SELF_TEST_Y, reg.SELF_TEST_Z)):
            self.regs[r] = ((a[i] >> 2) << 5) | g[i]
        self.regs[reg.SELF_TEST_A] = ((a[0] & 3) << 4) | ((a[1] & 3) << 2) | (a[2] & 3)
        self.fifo = bytearray()
        self.latest = np.zeros(6, dtype=np.int16)
        self._restart_clock()

    def _restart_clock(self) -> None:
        self._t0 = self.clock.now()
        self._ticks = 0
        self._sos: np.ndarray | None = None
        self._zi: np.ndarray | None = None

    @property
    def rate_hz(self) -> float:
        """True output rate: (gyro output rate)/(1 + SMPLRT_DIV), off by rate_error."""
        base = 8000.0 if self.regs[reg.CONFIG] & 7 in (0, 7) else reg.GYRO_OUTPUT_RATE_HZ
        return base / (1 + self.regs[reg.SMPLRT_DIV]) * (1 + self.rate_error)

    def _scales(self) -> tuple[float, float]:
        g_fs = reg.GYRO_FS_DPS[(self.regs[reg.GYRO_CONFIG] >> 3) & 3]
        a_fs = reg.ACCEL_FS_G[(self.regs[reg.ACCEL_CONFIG] >> 3) & 3]
        return a_fs / 32768 * reg.GRAVITY, g_fs / 32768 * np.pi / 180

    def _self_test_lsb(self) -> np.ndarray:
        out = np.zeros(6)
        a_lsb, g_lsb = self._scales()
        for i in range(3):
            if self.regs[reg.ACCEL_CONFIG] & (0x80 >> i):
                ft = 4096 * 0.34 * (0.92 / 0.34) ** ((ST_ACCEL_CODES[i] - 1) / 30)
                out[i] = ft * (1 + self.st_error) * (reg.GRAVITY / 4096) / a_lsb
            if self.regs[reg.GYRO_CONFIG] & (0x80 >> i):
                ft = (-1 if i == 1 else 1) * 25 * 131 * 1.046 ** (ST_GYRO_CODES[i] - 1)
                out[3 + i] = ft * (1 + self.st_error) * (np.pi / 180 / 131) / g_lsb
        return out

    def _frames(self, t: np.ndarray) -> np.ndarray:
        numbers = np.arange(self.sample_number, self.sample_number + t.size)
        if self.record_times:
            self.sample_times.append(t)
        self.sample_number += t.size
        if self.signal == "counter":
            return encode_counter(numbers)
        assert self.motion is not None
        m = self.motion.sample(t)
        rate = self.rate_hz
        a_lsb, g_lsb = self._scales()
        noise_g = GYRO_NOISE_DPS_RTHZ * np.pi / 180 * np.sqrt(rate / 2)
        noise_a = ACCEL_NOISE_G_RTHZ * reg.GRAVITY * np.sqrt(rate / 2)
        x = np.hstack(
            [
                m.accel + self.accel_bias + noise_a * self._rng.standard_normal((t.size, 3)),
                m.gyro + self.gyro_bias + noise_g * self._rng.standard_normal((t.size, 3)),
            ]
        )
        if self._sos is None:
            self._sos = dlpf_sos(self.regs[reg.CONFIG] & 7, rate)
            # start at steady state on the first sample: no power-on transient from gravity
            self._zi = np.ascontiguousarray(sosfilt_zi(self._sos)[:, :, None] * x[0][None, None, :])
        assert self._zi is not None
        lsb = np.array([a_lsb] * 3 + [g_lsb] * 3)
        # the DLPF (sosfilt's arithmetic, zi kept), the self-test offset, the ADC's rounding and clip
        return dlpf_counts(self._sos, self._zi, x, lsb, self._self_test_lsb())

    def update(self, now: float | None = None) -> None:
        """Take the samples due by now (or by `now`: the bus's time inside a combined transfer
        on a simulated clock); append them to the FIFO if it is on."""
        if self.regs[reg.PWR_MGMT_1] & reg.PWR_SLEEP:
            self._restart_clock()
            return
        now = self.clock.now() if now is None else now
        due = int(np.floor((now - self._t0) * self.rate_hz))
        if due <= self._ticks:
            return
        start = time.thread_time()
        self.generations += 1
        t = self._t0 + np.arange(self._ticks + 1, due + 1) / self.rate_hz
        self._ticks = due
        frames = self._frames(t)
        self.latest = frames[-1].astype(np.int16)
        fifo_on = self.regs[reg.USER_CTRL] & reg.USER_FIFO_EN
        if fifo_on and self.regs[reg.FIFO_EN] & reg.FIFO_EN_GYRO_ACCEL == reg.FIFO_EN_GYRO_ACCEL:
            self.fifo += frames.astype(">i2").tobytes()
            self.produced += len(frames)
            if len(self.fifo) > reg.FIFO_SIZE:  # the oldest bytes go: alignment is lost
                del self.fifo[: len(self.fifo) - reg.FIFO_SIZE]
                self.regs[reg.INT_STATUS] |= reg.INT_FIFO_OFLOW
        self.cpu_s += time.thread_time() - start

    def read(self, register: int, length: int, partial: bool = False, now: float | None = None) -> list[int]:
        self.update(now)
        if register == reg.FIFO_R_W:
            n = int(self._rng.integers(1, length)) if partial else length
            data = bytes(self.fifo[:n]).ljust(n, b"\xff")
            del self.fifo[:n]
            return list(data)
        if register == reg.FIFO_COUNT_H:
            self.regs[reg.FIFO_COUNT_H] = len(self.fifo) >> 8
            self.regs[reg.FIFO_COUNT_H + 1] = len(self.fifo) & 0xFF
        live = self.latest.astype(">i2").tobytes()
        self.regs[reg.ACCEL_XOUT_H : reg.ACCEL_XOUT_H + 14] = live[:6] + b"\x00\x00" + live[6:]
        out = list(self.regs[register : register + length])
        if register <= reg.INT_STATUS < register + length:
            self.regs[reg.INT_STATUS] = 0  # cleared by reading
        return out

    def write(self, register: int, value: int, now: float | None = None) -> None:
        self.update(now)
        if register == reg.PWR_MGMT_1 and value & reg.PWR_RESET:
            self.hard_reset()
            return
        if register == reg.WHO_AM_I:
            return
        old = self.regs[register]
        self.regs[register] = value & 0xFF
        if register == reg.USER_CTRL and value & reg.USER_FIFO_RESET:
            self.fifo.clear()
            self.regs[register] &= ~reg.USER_FIFO_RESET & 0xFF
        if register in (reg.SMPLRT_DIV, reg.CONFIG, reg.SIGNAL_PATH_RESET) or (
            register == reg.PWR_MGMT_1 and old & reg.PWR_SLEEP and not value & reg.PWR_SLEEP
        ):
            self._restart_clock()


def sil_pair(
    settings: ImuSettings,
    clock: Clock,
    motions: Mapping[str, MotionSource] | None = None,
    signal: str = "motion",
    rate_errors: dict[str, float] | None = None,
    bus_hz: float | None = 400e3,
    seed: int = 0,
) -> tuple[SimI2CBus, dict[str, SimMpu6050]]:
    """The scanner's two sensors (PL, SA) on one simulated bus, at the settings' addresses.

    Default clock errors +2.7 % and -3.1 %: inside the few % these parts show, and different, so
    a driver that assumed the nominal rate or one shared rate would be caught.
    """
    errors = rate_errors or {"pl": 0.027, "sa": -0.031}
    devices = {
        name: SimMpu6050(
            None if motions is None else motions[name],
            clock,
            rate_error=errors[name],
            signal=signal,
            seed=seed + i,
        )
        for i, name in enumerate(("pl", "sa"))
    }
    bus = SimI2CBus(clock, {settings.addresses[n]: d for n, d in devices.items()}, bus_hz=bus_hz, seed=seed)
    return bus, devices
