"""The IMU reader's steady state grows no heap: no mprotect on glibc's reserved heap, poll after poll.

Why it matters (docs/measurements/imureader.md): each page the reader's glibc arena gains, or
gets back after a trim, is a system call or a fault on the process's memory map, made with the
GIL held; the reader was caught waiting 453 ms so, in mprotect (docs/measurements/daemonfix.md).
The reader runs here against two MPU6050s simulated at the smbus2 boundary (a FIFO that fills at
1 kHz of a manual clock, frames copied from one preallocated block: the simulation itself
allocates next to nothing), in a fresh child process as the daemon sets it up
(tvsd.hw.heap.tune, the reader thread's own heap.reserve), and, as a control, with glibc
left as it is. The heap's growth is read from /proc/self/maps: glibc reserves a thread arena's
heap as PROT_NONE and grows it by mprotect, so the PROT_NONE bytes shrink by what it grew.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

_CHILD = r"""
import collections, ctypes, json, resource, sys, threading
from tvsd.hw import heap
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.imu_clock import ManualClock
from tvsd.hw.imu_reader import HEAP_RESERVE_BYTES, ImuReader
from tvsd.hw.imu_sensor_reader import SensorReader
from tvsd.hw.imu_settings import ImuSettings

I2C_M_RD = 1
WARM, WINDOW = int(sys.argv[2]), int(sys.argv[3])


class FifoBus:
    # Two MPU6050s at the smbus2 boundary: registers as written, WHO_AM_I, FIFO_COUNT and
    # FIFO_R_W of a FIFO filled at 1 kHz of the clock, INT_STATUS never flagged.
    def __init__(self, clock, rate_hz=1000.0):
        self.clock, self.rate = clock, rate_hz
        self.regs = {0x68: {}, 0x69: {}}
        self.popped = {0x68: 0.0, 0x69: 0.0}  # clock time up to which the FIFO was read
        self.frames = ctypes.create_string_buffer(b"\x01\x02" * (reg.FIFO_SIZE // 2))
        self.small = ctypes.create_string_buffer(2)

    def _count(self, addr):
        return min(int((self.clock.now() - self.popped[addr]) * self.rate), 85)

    def _read(self, addr, register, buf, n):
        if register == reg.FIFO_COUNT_H:
            c = self._count(addr) * reg.FRAME_BYTES
            self.small[0], self.small[1] = c >> 8, c & 0xFF
            ctypes.memmove(buf, self.small, 2)
        elif register == reg.FIFO_R_W:
            ctypes.memmove(buf, self.frames, n)
            self.popped[addr] += n // reg.FRAME_BYTES / self.rate
        else:
            v = self.regs[addr].get(register, 0)
            self.small[0] = 0x68 if register == reg.WHO_AM_I else 0 if register == reg.INT_STATUS else v
            ctypes.memmove(buf, self.small, 1)

    def _write(self, addr, register, value):
        self.regs[addr][register] = value
        if register == reg.USER_CTRL and value & reg.USER_FIFO_RESET:
            self.popped[addr] = self.clock.now()

    def read_byte_data(self, addr, register, force=None):
        self._read(addr, register, self.small, 1)
        return self.small.raw[0]

    def write_byte_data(self, addr, register, value, force=None):
        self._write(addr, register, value)

    def read_i2c_block_data(self, addr, register, length, force=None):
        buf = ctypes.create_string_buffer(length)
        self._read(addr, register, buf, length)
        return list(buf.raw)

    def i2c_rdwr(self, *msgs):
        pointer = 0
        for m in msgs:
            if m.flags & I2C_M_RD:
                self._read(m.addr, pointer, m.buf, m.len)
            else:
                pointer = m.buf[0][0]
                if m.len > 1:
                    self._write(m.addr, pointer, m.buf[1][0])

    def close(self):
        pass


from tvsd.hw.mpu6050 import Mpu6050

if sys.argv[1] == "daemon":
    heap.tune()
clock = ManualClock()
bus = FifoBus(clock)
settings = ImuSettings()
sensors = [SensorReader(Mpu6050(bus, n, settings, clock.sleep), clock) for n in ("pl", "sa")]
faults, grown, done = {}, {}, threading.Event()


def reserved_bytes():
    # PROT_NONE mappings: glibc's heaps' reserved rest (and the threads' guard pages): a heap
    # grown by mprotect shrinks it
    total = 0
    with open("/proc/self/maps") as f:
        for line in f:
            span, perms = line.split()[:2]
            if perms == "---p":
                lo, hi = span.split("-")
                total += int(hi, 16) - int(lo, 16)
    return total


def polled(sensor):  # on the reader thread, after each sensor's turn
    n = reader.joint_polls
    if sensor is sensors[-1] and n in (WARM, WARM + WINDOW) and n not in faults:
        faults[n] = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        grown[n] = reserved_bytes()
        if len(faults) == 2:
            done.set()


# The daemon's consumer: the event loop's thread takes each batch, keeps what it derives from it
# (a copy of its times: a recording's, a point stream's data) and drops the batch later, so the
# reader's blocks are freed on another thread and reused there, as in the daemon.
handed, kept, derived, stop = collections.deque(), collections.deque(maxlen=100), [], threading.Event()


def consume():
    while not stop.is_set():
        while handed:
            batch = handed.popleft()
            kept.append(batch)
            derived.append(batch.t.copy())
        stop.wait(0.0005)


consumer = threading.Thread(target=consume)
consumer.start()
reader = ImuReader(sensors, clock, on_batch=handed.append, on_poll=polled)
reader.heap_reserve = HEAP_RESERVE_BYTES
reader.start()
ok = done.wait(600)
reader.stop()
stop.set()
consumer.join()
print(json.dumps({
    "ok": ok, "faults": faults.get(WARM + WINDOW, 0) - faults.get(WARM, 0),
    "heap_grown": grown.get(WARM, 0) - grown.get(WARM + WINDOW, 0),
    "reserved": reader.heap_reserved, "samples": [s.samples for s in sensors],
    "lost": [s.lost for s in sensors], "refits_per_sensor": WINDOW // 100,
}))
"""


def _run(mode: str, warm: int, window: int) -> dict[str, object]:
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, mode, str(warm), str(window)],
        capture_output=True, text=True, timeout=900, check=True, env={**os.environ, "TVSD_MALLOC": ""},
    )  # fmt: skip
    got: dict[str, object] = json.loads(done.stdout)
    assert got["ok"], f"the reader did not reach {warm + window} polls: {got}"
    return got


@pytest.mark.slow
@pytest.mark.skipif(
    not Path("/proc/self/maps").is_file() or os.confstr("CS_GNU_LIBC_VERSION") is None,
    reason="the process's mappings (Linux /proc) and glibc's mallopt",
)
def test_the_reader_thread_grows_no_heap_in_its_steady_state():
    """After warm-up (4096 polls fill the clock fit's window, so its refit's arrays stop growing)
    3000 polls (60 s of sensor time) with the daemon's consumer on another thread. Left as glibc
    sets it (the control: the daemon before), the reader's arena lends its freed blocks to the
    consumer, which keeps some, and grows its heap by mprotect to replace them: 1.2-1.6 MB here
    (the soak's reader: ~1 MiB in 135 s, 84 mprotect calls). As the daemon sets it up
    (heap.tune, the reader thread's own heap.reserve of 16 MiB, ten times that) the heap is
    never grown in the window: exactly 0 bytes, since every byte glibc adds to a heap is
    mprotect-ed out of the PROT_NONE rest of its reservation, and nothing else in the window
    maps or unmaps PROT_NONE memory (no thread starts or ends)."""
    warm, window = 5000, 3000
    control = _run("glibc", warm, window)
    daemon = _run("daemon", warm, window)
    assert control["lost"] == daemon["lost"] == [0, 0]  # the simulation is a clean capture
    assert int(control["heap_grown"]) > 0, f"the probe does not see the heap grow: {control}"
    assert daemon["reserved"] is True
    assert daemon["heap_grown"] == 0, f"the reader's heap grew in its steady state: {daemon}"
