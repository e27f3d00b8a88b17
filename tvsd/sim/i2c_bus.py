"""A simulated I2C bus for the register-level twins (tvsd.sim.mpu6050), with fault injection.

SimI2CBus offers the smbus2.SMBus calls the driver makes (read_byte_data, write_byte_data,
read_i2c_block_data, i2c_rdwr, close) and fails the way the kernel does, with OSError(errno). It
charges each transaction's bit time to its Clock: a ManualClock runs faster than real time, a
MonotonicClock runs in real time.

Faults (Fault, scheduled in simulated time, per address or for all): "nack" (ENXIO), "eio" (EIO),
"partial" (FIFO reads pop 1..n-1 bytes, then fail with EIO; other transfers pass), "stall" (each
transaction hangs for stall_s, then ETIMEDOUT), "disconnect" (ENXIO, the sensor keeps sampling),
"power_cycle" (ENXIO, then the sensor comes back reset and asleep). Also `error_rate` (random EIO)
and, on the chip's side, a wrong WHO_AM_I (SimMpu6050's `who_am_i` argument).
"""

from __future__ import annotations

import errno
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.imu_clock import Clock, ManualClock

FAULT_KINDS = ("nack", "eio", "partial", "stall", "disconnect", "power_cycle")


class RegisterDevice(Protocol):
    """What the bus asks of the device at an address (SimMpu6050 is one)."""

    def read(
        self, register: int, length: int, partial: bool = False, now: float | None = None
    ) -> list[int]: ...

    def write(self, register: int, value: int, now: float | None = None) -> None: ...

    def hard_reset(self) -> None: ...


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
        devices: Mapping[int, RegisterDevice],
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
            now = self._msg_now = self._device_now(register, write)  # its data phase begins
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

    def _device_now(self, register: int, write: bool) -> float:
        """The time the devices see for a message of a combined transfer: its start plus the
        bits clocked until the message's data phase (a count latched then, a burst popping from
        then on: new frames join behind what it pops), each message after the one before, as on
        the wire. On a real-time clock (the transfer slept first, then runs its messages) a
        FIFO burst still pops at its data phase, which is past: the chip's FIFO peaks there
        and drains faster than it fills from then on, so whether it overflowed is decided then
        (popping at the transfer's end instead held the FIFO the whole transfer longer, ~12 ms
        of its 83 at 1 kHz, which the chip does not); every other message runs at the time
        itself: a count latched at the reply, as tight as the reader's bound takes it, and the
        twins never sample a plant's future."""
        if self._owed is None or not self.bus_hz:
            return self.clock.now()
        phase = self._t_start + self._owed / self.bus_hz
        if self._manual:
            return phase
        now = self.clock.now()
        return min(phase, now) if register == reg.FIFO_R_W and not write else now

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
            self._t_start = self.clock.now()
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
        from tvsd.hw.i2c_remote import fill_reads, rdwr_messages

        fill_reads(msgs, bytes(self.transfer(rdwr_messages(msgs))))

    def close(self) -> None:
        self.closed = True


def _transfer_bits(msgs: list[tuple[int, bool, int, bytes]]) -> int:
    """A combined transfer's bits on the wire, as SimI2CBus._transaction charges them: a
    [register] + read pair is one block read (27 + 9n + 2), [register, value] a byte write."""
    return sum(27 + 9 * n + 2 if read else 18 + 9 + 2 if n == 2 else 0 for _, read, n, _ in msgs)
