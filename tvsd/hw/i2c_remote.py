"""An I2C bus in another process: smbus2.SMBus's calls carried over a stream socket.

The SIL daemon's IMU twins (tvsd/sim/mpu6050.py) run in the SIL devices' process
(tvsd/sim/sil_process.py); the MPU6050 driver reaches them through `RemoteI2CBus`, which offers
the smbus2 calls the driver makes (read_byte_data, write_byte_data, read_i2c_block_data,
i2c_rdwr) and fails the way the kernel does, with OSError(errno): the driver runs the code path
it runs on /dev/i2c-N. One call is one request and one reply; the caller blocks as it would in
the ioctl, for the bit time the twin charges there. `i2c_rdwr` carries all its messages in one
request (the driver's FIFO read: one round trip, as it is one ioctl on hardware).

Failures: the other end closed (the process died) → EIO; no reply within `timeout_s` (1 s, the
Linux I2C adapters' default) → ETIMEDOUT, a late reply is dropped by its sequence number.

Wire (little-endian): request ``<HBH`` (sequence, op, payload length) + payload; reply ``<HhH``
(sequence, 0 or an errno, length) + data. Payloads: READ_BYTE addr, register; WRITE_BYTE addr,
register, value; READ_BLOCK addr, register, length; RDWR one ``<BBH`` (addr, 1 = read, length)
per message, a write's bytes after it; the reply holds the read messages' bytes in order.
"""

from __future__ import annotations

import ctypes
import errno
import os
import socket
import struct
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

REQUEST = struct.Struct("<HBH")
REPLY = struct.Struct("<HhH")
MESSAGE = struct.Struct("<BBH")
OP_READ_BYTE, OP_WRITE_BYTE, OP_READ_BLOCK, OP_RDWR = 1, 2, 3, 4
I2C_M_RD = 0x0001  # linux/i2c.h, as smbus2.i2c_msg.flags
RDWR_MAX_MSGS = 42  # I2C_RDWR_IOCTL_MAX_MSGS: the kernel refuses more in one ioctl
TIMEOUT_S = 1.0  # a twin's transfer takes < 1 ms (a stall fault: 50 ms); the kernel's adapters give 1 s
RTT_EDGES_S = (0.002, 0.005, 0.01, 0.02, 0.05)  # round trips counted over each (stats())


def _oserror(code: int, detail: str = "") -> OSError:
    return OSError(code, os.strerror(code) + (f" ({detail})" if detail else ""))


def recv_exact(sock: socket.socket, n: int) -> bytes:
    """n bytes, or ConnectionError at the end of the stream."""
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("end of stream")
        buf += chunk
    return bytes(buf)


class RemoteI2CBus:
    """smbus2.SMBus's calls (those tvsd.hw.mpu6050 makes) over a connected stream socket."""

    def __init__(self, sock: socket.socket, timeout_s: float = TIMEOUT_S) -> None:
        self._sock = sock
        self._sock.settimeout(timeout_s)
        self._lock = threading.Lock()  # one request in flight
        self._seq = 0
        self.requests = 0  # round trips made (the driver's FIFO read must cost one)
        self.closed = False
        self.rtt_max_s = self.rtt_sum_s = 0.0
        self.rtt_over = [0] * len(RTT_EDGES_S)

    def stats(self) -> dict[str, object]:
        """Round trips: count, mean and max (ms), and how many took over each of RTT_EDGES_S
        (a FIFO read of n frames holds the bus ~0.3·n ms at 400 kHz: 20 frames, 6 ms)."""
        n = max(self.requests, 1)
        return {
            "requests": self.requests,
            "rtt_mean_ms": round(1e3 * self.rtt_sum_s / n, 3),
            "rtt_max_ms": round(1e3 * self.rtt_max_s, 3),
            "rtt_over_ms": {f"{1e3 * e:g}": c for e, c in zip(RTT_EDGES_S, self.rtt_over, strict=True)},
        }

    def _call(self, op: int, payload: bytes) -> bytes:
        if self.closed:
            raise _oserror(errno.EBADF)
        with self._lock:
            self._seq = (self._seq + 1) & 0xFFFF
            self.requests += 1
            t0 = time.monotonic()
            try:
                self._sock.sendall(REQUEST.pack(self._seq, op, len(payload)) + payload)
                while True:
                    seq, code, n = REPLY.unpack(recv_exact(self._sock, REPLY.size))
                    data = recv_exact(self._sock, n) if n else b""
                    if seq == self._seq:  # else the late reply to a request that timed out
                        break
            except TimeoutError:
                raise _oserror(errno.ETIMEDOUT, "the SIL devices' process did not answer the bus") from None
            except OSError as exc:  # ConnectionError, EPIPE, EBADF: the process is gone
                raise _oserror(errno.EIO, f"the SIL devices' process is gone: {exc}") from None
            rtt = time.monotonic() - t0
            self.rtt_sum_s += rtt
            self.rtt_max_s = max(self.rtt_max_s, rtt)
            for i, edge in enumerate(RTT_EDGES_S):
                if rtt > edge:
                    self.rtt_over[i] += 1
        if code:
            raise _oserror(code)
        return data

    def read_byte_data(self, i2c_addr: int, register: int, force: bool | None = None) -> int:
        return self._call(OP_READ_BYTE, bytes((i2c_addr & 0x7F, register & 0xFF)))[0]

    def write_byte_data(self, i2c_addr: int, register: int, value: int, force: bool | None = None) -> None:
        self._call(OP_WRITE_BYTE, bytes((i2c_addr & 0x7F, register & 0xFF, value & 0xFF)))

    def read_i2c_block_data(
        self, i2c_addr: int, register: int, length: int, force: bool | None = None
    ) -> list[int]:
        if not 0 < length <= 32:  # the smbus2 / SMBus limit
            raise ValueError("Desired block length over 32 bytes")
        return list(self._call(OP_READ_BLOCK, bytes((i2c_addr & 0x7F, register & 0xFF, length))))

    def i2c_rdwr(self, *msgs: Any) -> None:
        """smbus2's combined transfer: `msgs` are smbus2.i2c_msg (addr, flags, len, buf); read
        messages get their bytes in `buf`, as from the ioctl."""
        if len(msgs) > RDWR_MAX_MSGS:
            raise _oserror(errno.EINVAL, f"{len(msgs)} messages, the kernel takes {RDWR_MAX_MSGS}")
        parts = []
        for m in msgs:
            read = bool(m.flags & I2C_M_RD)
            parts.append(MESSAGE.pack(m.addr & 0x7F, int(read), m.len))
            if not read:
                parts.append(ctypes.string_at(m.buf, m.len))
        fill_reads(msgs, self._call(OP_RDWR, b"".join(parts)))

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._sock.close()


def parse_rdwr(payload: bytes) -> list[tuple[int, bool, int, bytes]]:
    """The RDWR payload as (addr, read, length, written bytes) per message."""
    out, at = [], 0
    while at < len(payload):
        addr, read, n = MESSAGE.unpack_from(payload, at)
        at += MESSAGE.size
        data = b"" if read else payload[at : at + n]
        at += 0 if read else n
        out.append((addr, bool(read), n, data))
    return out


Handler = Callable[[int, bytes], bytes]


def serve(sock: socket.socket, handle: Handler) -> None:
    """Answer RemoteI2CBus requests until the socket ends: `handle(op, payload)` returns the
    reply's bytes or raises OSError (its errno goes back) or ValueError (EINVAL)."""
    while True:
        try:
            seq, op, n = REQUEST.unpack(recv_exact(sock, REQUEST.size))
            payload = recv_exact(sock, n) if n else b""
        except OSError:  # ConnectionError included: the daemon closed the bus or died
            return
        data, code = b"", 0
        try:
            data = handle(op, payload)
        except OSError as exc:
            code = exc.errno or errno.EIO
        except (ValueError, IndexError, struct.error):
            code = errno.EINVAL
        try:
            sock.sendall(REPLY.pack(seq, code, len(data)) + data)
        except OSError:
            return


class BusHandler:
    """The server side over an SMBus-like object with i2c_rdwr-style pairs (tvsd.sim.i2c_bus.SimI2CBus)."""

    def __init__(self, bus: Any) -> None:
        self.bus = bus

    def __call__(self, op: int, payload: bytes) -> bytes:
        if op == OP_READ_BYTE:
            addr, register = payload[0], payload[1]
            return bytes((self.bus.read_byte_data(addr, register),))
        if op == OP_WRITE_BYTE:
            self.bus.write_byte_data(payload[0], payload[1], payload[2])
            return b""
        if op == OP_READ_BLOCK:
            return bytes(self.bus.read_i2c_block_data(payload[0], payload[1], payload[2]))
        if op == OP_RDWR:
            msgs = parse_rdwr(payload)
            if len(msgs) > RDWR_MAX_MSGS:
                raise ValueError("too many messages")
            return bytes(self.bus.transfer(msgs))
        raise ValueError(f"unknown op {op}")


def rdwr_messages(msgs: Sequence[Any]) -> list[tuple[int, bool, int, bytes]]:
    """smbus2.i2c_msg objects as (addr, read, length, written bytes): for a bus model's i2c_rdwr."""
    return [
        (
            m.addr,
            bool(m.flags & I2C_M_RD),
            m.len,
            b"" if m.flags & I2C_M_RD else ctypes.string_at(m.buf, m.len),
        )
        for m in msgs
    ]


def fill_reads(msgs: Sequence[Any], data: bytes) -> None:
    """A combined transfer's reply into its read messages' buffers, in order, as the ioctl fills them."""
    at = 0
    for m in msgs:
        if m.flags & I2C_M_RD:
            ctypes.memmove(m.buf, data[at : at + m.len], m.len)
            at += m.len
