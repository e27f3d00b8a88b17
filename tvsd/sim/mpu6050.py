"""Simulated MPU6050s on a simulated I2C bus: the driver's twin at the register level.

SimI2CBus offers the smbus2.SMBus calls the driver makes (read_byte_data, write_byte_data,
read_i2c_block_data, i2c_rdwr, close) and fails the way the kernel does, with OSError(errno). Each
SimMpu6050 keeps a register map and a 1024-byte FIFO filled, on every access, with the samples its
own clock (nominal rate times 1 + rate_error: these oscillators run a few % off) produced since the
last access. The time comes from a Clock: a ManualClock runs faster than real time (and the bus
charges each transaction's bit time to it), a MonotonicClock runs in real time.

Signals: "motion" samples a MotionSource through a DLPF model (`dlpf_sos`: the datasheet's
bandwidth and delay), adds the datasheet's noise and a bias, and quantizes to int16 at the
configured range (clipping like the chip). "counter" puts a running sample number and a check
word in each frame, so tests can see exactly which samples the driver delivered, lost, or
misaligned.

Faults (Fault, scheduled in simulated time, per address or for all): "nack" (ENXIO), "eio" (EIO),
"partial" (FIFO reads pop 1..n-1 bytes, then fail with EIO; other transfers pass), "stall" (each
transaction hangs for stall_s, then ETIMEDOUT), "disconnect" (ENXIO, the sensor keeps sampling),
"power_cycle" (ENXIO, then the sensor comes back reset and asleep). Also `error_rate` (random EIO)
and a wrong WHO_AM_I (the `who_am_i` argument).
"""

from __future__ import annotations

import ctypes
import errno
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.signal import butter, group_delay, sos2tf, sosfilt, sosfilt_zi

from tvsd.hw import mpu6050 as reg
from tvsd.hw.imu_clock import Clock, ManualClock
from tvsd.sim.imu_motion import MotionSource

GYRO_NOISE_DPS_RTHZ = 0.005  # rate noise spectral density (datasheet)
ACCEL_NOISE_G_RTHZ = 400e-6  # power spectral density (datasheet)
# Self-test codes of this simulated part; the response equals the factory trim times 1 + error.
ST_GYRO_CODES = (14, 17, 12)
ST_ACCEL_CODES = (16, 15, 18)
FAULT_KINDS = ("nack", "eio", "partial", "stall", "disconnect", "power_cycle")


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
        self.who_am_i, self.rate_error, self.st_error = who_am_i, rate_error, st_error
        rng = np.random.default_rng(seed)
        self._rng = rng
        self.gyro_bias = rng.uniform(-0.02, 0.02, 3)  # rad/s (about 1 deg/s)
        self.accel_bias = rng.uniform(-0.3, 0.3, 3)  # m/s^2 (about 30 mg)
        self.produced = 0  # frames written into the FIFO, including those later dropped
        self.sample_number = 0  # every sample taken, FIFO on or off (the counter signal)
        self.cpu_s = 0.0  # process time spent generating samples (to separate it in benchmarks)
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
            self._zi = sosfilt_zi(self._sos)[:, :, None] * x[0][None, None, :]
        x, self._zi = sosfilt(self._sos, x, axis=0, zi=self._zi)
        lsb = np.array([a_lsb] * 3 + [g_lsb] * 3)
        counts = np.rint(x / lsb + self._self_test_lsb())
        return np.clip(counts, -32768, 32767).astype(np.int64)

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
        start = time.process_time()
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
        self.cpu_s += time.process_time() - start

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


@dataclass(frozen=True)
class Fault:
    """A fault active on [start, end) in bus time, for one address or (None) every address."""

    kind: str
    start: float
    end: float
    address: int | None = None
    op: str = "any"  # "read", "write" or "any" transfers

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS or self.end < self.start:
            raise ValueError(f"bad fault {self}: kind one of {FAULT_KINDS}, end >= start")
        if self.op not in ("any", "read", "write"):
            raise ValueError(f"bad fault {self}: op is read, write or any")


class SimI2CBus:
    """The smbus2.SMBus subset the driver uses, over simulated devices, with fault injection."""

    def __init__(
        self,
        clock: Clock,
        devices: dict[int, SimMpu6050],
        bus_hz: float | None = 400e3,
        error_rate: float = 0.0,
        stall_s: float = 0.05,
        seed: int = 0,
    ) -> None:
        self.clock, self.devices, self.bus_hz = clock, devices, bus_hz
        self.error_rate, self.stall_s = error_rate, stall_s
        self.faults: list[Fault] = []
        self._rng = np.random.default_rng(seed)
        self._cycled: set[tuple[int, float]] = set()
        self.transactions = 0
        self.errors = 0
        self.bits = 0
        self.closed = False
        self._owed: int | None = None  # bits of the combined transfer in progress, not yet slept
        self._t_start = 0.0  # when that transfer began
        self._msg_now = 0.0  # the devices' time for the message in progress
        self._manual = isinstance(clock, ManualClock)

    def _transaction(self, addr: int, nbytes: int, register: int, write: bool) -> str | None:
        """Charge bus time, apply faults; returns 'partial' when a FIFO read must half-happen."""
        if self.closed:
            raise OSError(errno.EBADF, os.strerror(errno.EBADF))
        self.transactions += 1
        header = 18 if write else 27  # start, address, register (+ restart, address)
        bits = header + 9 * nbytes + 2
        self.bits += bits
        if self._owed is not None:  # inside a combined transfer: slept once at its end
            self._owed += header
            now = self._msg_now = self._device_now()  # its data phase begins
            self._owed += bits - header
        else:
            if self.bus_hz:
                self.clock.sleep(bits / self.bus_hz)
            now = self._msg_now = self.clock.now()
        result = None
        for f in self.faults:
            if f.address not in (None, addr) or (f.op != "any" and (f.op == "write") != write):
                continue
            if f.kind == "power_cycle" and now >= f.end and (addr, f.start) not in self._cycled:
                if now >= f.start and addr in self.devices:
                    self._cycled.add((addr, f.start))
                    self.devices[addr].hard_reset()
                continue
            if not f.start <= now < f.end:
                continue
            if f.kind == "stall":
                self.clock.sleep(self.stall_s)
                self._raise(errno.ETIMEDOUT)
            if f.kind in ("nack", "disconnect", "power_cycle"):
                self._raise(errno.ENXIO)
            if f.kind == "eio":
                self._raise(errno.EIO)
            if f.kind == "partial" and not write and register == reg.FIFO_R_W:
                result = "partial"
        if addr not in self.devices:
            self._raise(errno.ENXIO)
        if self.error_rate and self._rng.random() < self.error_rate:
            self._raise(errno.EIO)
        return result

    def _device_now(self) -> float:
        """The time the devices see. Inside a combined transfer on a simulated clock (slept
        once at the end): its start plus the bits clocked until the message's data phase (a
        count latched then, a burst popping from then on: new frames join behind what it
        pops), each message after the one before, as on the wire. On a real-time clock the
        time itself: the twins must not sample a plant's future."""
        if self._owed is not None and self._manual and self.bus_hz:
            return self._t_start + self._owed / self.bus_hz
        return self.clock.now()

    def _raise(self, code: int) -> None:
        self.errors += 1
        raise OSError(code, os.strerror(code))

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        self._transaction(i2c_addr, 1, register, write=False)
        return self.devices[i2c_addr].read(register, 1, now=self._msg_now)[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._transaction(i2c_addr, 1, register, write=True)
        self.devices[i2c_addr].write(register, value, now=self._msg_now)

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if not 0 < length <= 32:  # the smbus2 / SMBus limit
            raise ValueError("Desired block length over 32 bytes")
        partial = self._transaction(i2c_addr, length, register, write=False) == "partial"
        data = self.devices[i2c_addr].read(register, length, partial=partial)
        if partial:
            self._raise(errno.EIO)
        return data

    def transfer(self, msgs: list[tuple[int, bool, int, bytes]]) -> list[int]:
        """A combined transfer (one I2C_RDWR ioctl): messages (addr, read, length, written
        bytes), each pair [register] + read n one block read's transaction, [register, value] a
        byte write. The read messages' bytes, in order; a failing message fails the whole, as
        the kernel then copies nothing back (what the earlier reads popped is gone)."""
        out: list[int] = []
        if self.bus_hz and not self._manual:
            # Real time: the whole bit time first, then every message's data phase (one sleep,
            # one GIL retake). A count latched at the start and slept after made the reader's
            # count times loose by the sleep and the GIL's retake after it (ms under load): its
            # clock fit (a lower envelope of t - K/rate over the last 100 reads) then stepped by
            # ms as tight reads aged out (SIL coherence with the plant 0.94-0.98, not > 0.98).
            # Here a count is latched just before the reply, as the single-message reads do.
            self.clock.sleep(_transfer_bits(msgs) / self.bus_hz)
            self._owed = 0  # inside a combined transfer: no sleep per message
            try:
                self._messages(msgs, out)
            finally:
                self._owed = None
            return out
        self._owed, self._t_start = 0, self.clock.now()
        try:
            self._messages(msgs, out)
        finally:
            owed, self._owed = self._owed, None
            if self.bus_hz and owed:
                # Simulated clock: one sleep for the whole transfer, as the kernel's ioctl blocks
                # once (a sleep per transaction released and retook the GIL each time: a 21-pair
                # FIFO read's ~6 ms of bus time took 20-40 ms beside the plant's thread), until
                # the transfer's end on the bus: the twins' computing happens within its bit time.
                self.clock.sleep(max(self._t_start + owed / self.bus_hz - self.clock.now(), 0.0))
        return out

    def _messages(self, msgs: list[tuple[int, bool, int, bytes]], out: list[int]) -> None:
        i = 0
        while i < len(msgs):
            addr, read, n, data = msgs[i]
            if not read and n == 2:
                self.write_byte_data(addr, data[0], data[1])
                i += 1
            elif not read and n == 1 and i + 1 < len(msgs) and msgs[i + 1][1] and msgs[i + 1][0] == addr:
                length = msgs[i + 1][2]
                if not 0 < length <= reg.FIFO_SIZE:
                    raise ValueError(f"read of {length} bytes")
                partial = self._transaction(addr, length, data[0], write=False) == "partial"
                out += self.devices[addr].read(data[0], length, partial=partial, now=self._msg_now)
                if partial:
                    self._raise(errno.EIO)
                i += 2
            else:
                raise ValueError("i2c_rdwr: only [register] + read and [register, value] messages")

    def i2c_rdwr(self, *msgs: Any) -> None:
        """smbus2.SMBus.i2c_rdwr over the twins: smbus2.i2c_msg messages, read buffers filled."""
        from tvsd.hw.i2c_remote import I2C_M_RD, rdwr_messages

        data = bytes(self.transfer(rdwr_messages(msgs)))
        at = 0
        for m in msgs:
            if m.flags & I2C_M_RD:
                ctypes.memmove(m.buf, data[at : at + m.len], m.len)
                at += m.len

    def close(self) -> None:
        self.closed = True


def _transfer_bits(msgs: list[tuple[int, bool, int, bytes]]) -> int:
    """A combined transfer's bits on the wire, as SimI2CBus._transaction charges them: a
    [register] + read pair is one block read (27 + 9n + 2), [register, value] a byte write."""
    return sum(27 + 9 * n + 2 if read else 18 + 9 + 2 if n == 2 else 0 for _, read, n, _ in msgs)


def sil_pair(
    settings: reg.ImuSettings,
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
