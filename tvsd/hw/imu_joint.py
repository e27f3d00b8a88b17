"""Both MPU6050s polled together: two combined transfers a poll, each FIFO read in one burst.

Why: a poll of one sensor alone is two round trips (FIFO_COUNT, then the frames with INT_STATUS
riding in the same transfer), so the reader paid four a period for two sensors, each a syscall
and a wait for the GIL after it (on hardware and SIL alike), on a bus that reading 2 × 1 kHz
frames in 24-byte block reads keeps ~63 % busy. What is left of the period for those fixed
costs is what lets a late poll catch up: a cycle of period C reads C worth of frames in u·C of
bus time plus the fixed cost c, so after a delay the polls run back to back at
C = c / (1 − u); when c grows under load (each wait for the GIL, the other process's) C reaches
the FIFO's 85 ms and the FIFO overflows with no single stall to blame (a soak: 26 overflows in
150 s, the longest wake-up of the reader 6 ms late, no stall of either process over 50 ms).
Here a poll of both is two round trips (c halved) and each FIFO is read in one burst
message (u: 63 % → 55 %: 9 bits a byte, no header per 24 bytes):
1. one I2C_RDWR with both FIFO_COUNT reads;
2. one I2C_RDWR with, per sensor, a burst read of FIFO_R_W for the whole frames counted (the
   register does not auto-increment: a burst read pops the FIFO byte after byte, as the Linux
   inv_mpu6050 driver reads it) and INT_STATUS after it (the overflow check of
   tvsd.hw.imu_sensor_reader, which clears it).
Same transactions on the wire, per sensor, as tvsd.hw.mpu6050.Mpu6050's own poll; the policy
(alignment, epochs, overflow = every frame of that read discarded and counted lost) is the
SensorReader's. Used when every sensor's next poll is a plain one (SensorReader.plain) and the
bus has i2c_rdwr (smbus2 on /dev/i2c-N, the twins, tvsd.hw.i2c_remote); otherwise, and after any
failure, each sensor polls alone, which tells whose the fault is.
"""

from __future__ import annotations

import errno
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from smbus2 import i2c_msg

from tvsd.errors import DeviceError
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.mpu6050 import Mpu6050

if TYPE_CHECKING:
    from tvsd.hw.imu_reader import ImuReader
    from tvsd.hw.imu_sensor_reader import SensorReader

MAX_BURST = reg.FIFO_SIZE // reg.FRAME_BYTES  # 85 frames: 1020 bytes, under i2c-dev's 8192 a message
# A FIFO_COUNT read on the wire: start, address, register, restart, address, 2 bytes (9 bits
# each with the ACK), stop. At the nominal 400 kHz (hil/README.md): each count read after a
# sensor's in the same transfer puts its latch that much before the transfer's end.
COUNT_BITS = 27 + 9 * 2 + 2
BUS_HZ = 400e3


def count_times(t_end: float, sensors: int) -> list[float]:
    """When each sensor's FIFO_COUNT was read, from the time the combined read returned (the
    clock fit takes a count's time as an upper bound of its latch: ClockFit.t0)."""
    return [t_end - (sensors - 1 - i) * COUNT_BITS / BUS_HZ for i in range(sensors)]


def _fail(drivers: Sequence[Mpu6050], what: str, exc: OSError, popped: bool) -> DeviceError:
    where = ", ".join(f"0x{d.address:02x} ({d.name})" for d in drivers)
    err = DeviceError(
        f"I2C bus {drivers[0].settings.bus} addresses {where}: combined {what} failed "
        f"({exc.strerror or exc}); each sensor is polled alone next"
    )
    # a NACK means "nothing moved" only for a transfer that popped nothing
    err.errno = errno.EIO if popped else exc.errno
    return err


def read_counts(drivers: Sequence[Mpu6050]) -> list[int]:
    """FIFO_COUNT (bytes) of each sensor, in one combined transfer."""
    reads = [i2c_msg.read(d.address, 2) for d in drivers]
    msgs = [
        m
        for d, r in zip(drivers, reads, strict=True)
        for m in (i2c_msg.write(d.address, [reg.FIFO_COUNT_H]), r)
    ]
    try:
        drivers[0].bus.i2c_rdwr(*msgs)  # type: ignore[attr-defined]
    except OSError as exc:
        raise _fail(drivers, "read of FIFO_COUNT", exc, popped=False) from exc
    out = []
    for r in reads:
        b = bytes(r)
        out.append((b[0] << 8) | b[1])
    return out


def read_fifos(
    drivers: Sequence[Mpu6050], frames: Sequence[int], out: Sequence[list[np.ndarray]]
) -> list[bool]:
    """Per sensor, `frames[i]` whole frames (≤ MAX_BURST) in one burst read of FIFO_R_W, appended
    to `out[i]` as a (n, 6) int16 array, then INT_STATUS: whether its FIFO overflowed since the
    last status read. One combined transfer; if it fails, what it popped is gone (DeviceError)."""
    msgs = []
    data: list[i2c_msg | None] = []
    status = []
    for d, n in zip(drivers, frames, strict=True):
        if not 0 <= n <= MAX_BURST:
            raise ValueError(f"{d.name}: {n} frames in one burst (0..{MAX_BURST})")
        r = i2c_msg.read(d.address, n * reg.FRAME_BYTES) if n else None
        if r is not None:
            msgs += [i2c_msg.write(d.address, [reg.FIFO_R_W]), r]
        s = i2c_msg.read(d.address, 1)
        msgs += [i2c_msg.write(d.address, [reg.INT_STATUS]), s]
        data.append(r)
        status.append(s)
    try:
        drivers[0].bus.i2c_rdwr(*msgs)  # type: ignore[attr-defined]
    except OSError as exc:
        raise _fail(drivers, "read of FIFO_R_W and INT_STATUS", exc, popped=True) from exc
    for r, o in zip(data, out, strict=True):
        if r is not None:
            o.append(np.frombuffer(bytes(r), dtype=">i2").reshape(-1, 6).astype(np.int16))
    return [bool(bytes(s)[0] & reg.INT_FIFO_OFLOW) for s in status]


def possible(reader: ImuReader) -> bool:
    """Whether the reader's next step is a joint poll: the sensors share a bus with i2c_rdwr, one
    is due, and every one's next poll is plain (SensorReader.plain)."""
    if len(reader.sensors) < 2 or not reader.joint:
        return False
    bus = reader.sensors[0].driver.bus
    if not hasattr(bus, "i2c_rdwr") or any(s.driver.bus is not bus for s in reader.sensors):
        return False
    now = reader.clock.now()
    return any(s.next_time <= now for s in reader.sensors) and all(s.plain() for s in reader.sensors)


def poll(reader: ImuReader) -> list[SensorReader]:
    """One poll of all the reader's sensors; the sensors it polled (none: the count
    read failed, nothing moved, each polls alone now and finds whose fault it is). One
    schedule for all from here: the earliest due time's."""
    sensors = reader.sensors
    due = min(s.next_time for s in sensors)
    try:
        counts = read_counts([s.driver for s in sensors])
    except DeviceError:
        return []
    times = count_times(reader.clock.now(), len(sensors))
    reader.joint_polls += 1
    todo: list[tuple[SensorReader, int]] = []
    for s, count, t_count in zip(sensors, counts, times, strict=True):
        s.next_time = due
        try:
            frames = s.counted(count, t_count)
        except DeviceError as exc:
            s._failed(str(exc))
            continue
        if frames is None:  # misaligned, and resynced
            s._ok()
        else:
            if s._stale():  # nothing for 5 polls, and still nothing: asleep? (its own poll checks)
                s._check_running = True
            todo.append((s, frames))
    if not todo:
        return list(sensors)
    # the reader's own time between its two transfers (its Python and the GIL's waits)
    reader.joint_gap_max_s = max(reader.joint_gap_max_s, reader.clock.now() - times[-1])
    try:
        flags = read_fifos([s.driver for s, _ in todo], [n for _, n in todo], [s._pending for s, _ in todo])
    except DeviceError as exc:
        for s, _ in todo:  # what it popped is gone, maybe whole frames: realign each
            s._need_resync = True
            s._failed(str(exc))
        return list(sensors)
    for (s, _), overflow in zip(todo, flags, strict=True):
        try:
            s.read_done(overflow, s._t_count)
        except DeviceError as exc:
            s._failed(str(exc))
        else:
            s._ok()
    return list(sensors)
