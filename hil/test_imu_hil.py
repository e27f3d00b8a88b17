"""Hardware-in-the-loop: the same driver and reader on the scanner's two real MPU6050s.

Run on the scanner: `pytest hil/test_imu_hil.py -m hil -s` (see hil/README.md, "IMU (MPU6050)").
TVSD_IMU_BUS picks the bus (default 1); TVSD_HIL_RPS, if set, is the rotation rate the SA motor
is running at during the capture test (start it with tvsctl first), and the imbalance line must
then be found there. Everything skips with the reason where no I2C bus is present.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from tvsd.cli.imu import dominant_line, run_capture, sa_alpha
from tvsd.hw.imu_clock import MonotonicClock
from tvsd.hw.imu_reader import ImuReader
from tvsd.hw.imu_sensor_reader import SensorReader
from tvsd.hw.imu_settings import ImuSettings
from tvsd.hw.mpu6050 import Mpu6050, bus_budget
from tvsd.hw.mpu6050_registers import FRAME_BYTES, GENUINE_ID

BUS = int(os.environ.get("TVSD_IMU_BUS", "1"))
DEVICE = Path(f"/dev/i2c-{BUS}")
pytestmark = [
    pytest.mark.hil,
    pytest.mark.skipif(
        not DEVICE.exists(),
        reason=f"no {DEVICE}: not on the scanner, or I2C not enabled (hil/README.md)",
    ),
]
S = ImuSettings(bus=BUS)


@pytest.fixture
def bus():
    import smbus2

    b = smbus2.SMBus(BUS)
    yield b
    b.close()


@pytest.mark.parametrize("name", ["pl", "sa"])
def test_probe(bus, name):
    chip = Mpu6050(bus, name, S, time.sleep).probe()
    print(f"{name}: {chip} at 0x{S.addresses[name]:02x}")


@pytest.mark.parametrize("name", ["pl", "sa"])
def test_datasheet_self_test(bus, name):
    drv = Mpu6050(bus, name, S, time.sleep)
    drv.start()
    if drv.chip_id != GENUINE_ID:
        pytest.skip(f"{name}: a clone (WHO_AM_I 0x{drv.chip_id:02x}): no MPU6050 self-test trim")
    result = drv.self_test(samples=100)
    print(name, result)
    assert result.passed, f"{name}: self-test change from factory trim beyond 14 %: {result}"


def test_fifo_rate_against_the_wall_clock(bus):
    clock = MonotonicClock()
    readers = [SensorReader(Mpu6050(bus, n, S, clock.sleep), clock) for n in ("pl", "sa")]
    start = time.monotonic()
    batches = ImuReader(readers, clock).run_for(6.0)
    wall = time.monotonic() - start
    for r in readers:
        n = sum(len(b.k) for b in batches if b.sensor == r.name)
        rate = r.fit.rate()
        print(f"{r.name}: fitted {rate:.2f} Hz, {n} samples in {wall:.2f} s, {r.status()}")
        # the oscillator's tolerance is a few %: 5 % flags a wrong divider or DLPF setting
        assert abs(rate / S.sample_rate_hz - 1) < 0.05
        # what arrived matches the fitted rate over the time sampled (bring-up 0.13 s, one poll)
        assert abs((n + r.lost) / (rate * (wall - 0.13)) - 1) < 0.02
        assert r.overflows == 0, "FIFO overflowed on a healthy bus: the poll loop is too slow"


def test_capture_10_s(bus):
    recs = run_capture(bus, S, MonotonicClock(), 10.0)
    for name, rec in recs.items():
        print(name, rec.status)
        assert rec.status["lost"] == 0 and rec.status["overflows"] == 0
    alpha, fs = sa_alpha(recs["sa"], 0)
    f, amp, _, _ = dominant_line(alpha, fs)
    print(f"SA dominant line {f:.2f} Hz, {amp:.3g} rad/s^2")
    rps = os.environ.get("TVSD_HIL_RPS")
    if rps:  # 10 s record: 0.1 Hz bins; the motor's speed ripple widens the line a little
        assert abs(f - float(rps)) < 0.5


def test_bus_payload_rate_measured_against_the_budget(bus):
    """Bytes/s of FIFO payload actually moved, against the bus_budget() computed figure."""
    drv = Mpu6050(bus, "sa", S, time.sleep)
    drv.start()
    time.sleep(0.08)  # let the FIFO fill (~80 frames)
    frames: list[np.ndarray] = []
    t0 = time.perf_counter()
    drv.read_frames(drv.fifo_count() // FRAME_BYTES, frames)
    dt = time.perf_counter() - t0
    payload = sum(len(f) for f in frames) * FRAME_BYTES
    hz = _bus_hz()
    budget = bus_budget(S, sensors=1, bus_hz=hz)
    # at 122.5 bus bits per frame the bus alone allows hz/122.5*12 bytes/s; kernel overhead
    # per transfer only lowers it
    ceiling = hz / ((27 + 9 * 24 + 2) / 2) * FRAME_BYTES
    print(
        f"measured {payload / dt:.0f} B/s payload, bus ceiling {ceiling:.0f} B/s at {hz:.0f} Hz, "
        f"budget for 1 kHz: {budget['payload_bytes_per_s']:.0f} B/s"
    )
    assert payload / dt <= ceiling * 1.02
    assert payload / dt > budget["payload_bytes_per_s"] * 1.2, "bus too slow for 1 kHz + margin"


def _bus_hz() -> float:
    node = Path(f"/sys/class/i2c-adapter/i2c-{BUS}/of_node/clock-frequency")
    if node.exists():
        return float(int.from_bytes(node.read_bytes()[:4], "big"))
    return 400e3
