"""The MPU6050 driver against its register-level twin (no mocks: the same code as on the bus)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tvsd.errors import EXIT_UNAVAILABLE, DeviceError, UsageError
from tvsd.hw import mpu6050_registers as reg
from tvsd.hw.angular_acceleration import AngularAccelerationStream, angular_acceleration
from tvsd.hw.imu_clock import ManualClock
from tvsd.hw.imu_settings import ImuSettings, to_si
from tvsd.hw.mpu6050 import Mpu6050, bus_budget
from tvsd.sim.i2c_bus import SimI2CBus
from tvsd.sim.imu_motion import SyntheticMotion, SyntheticParams
from tvsd.sim.mpu6050 import SimMpu6050, decode_counter, dlpf_sos


def rig(who_am_i: int = 0x68, signal: str = "counter", **motion: float):
    clock = ManualClock()
    source = SyntheticMotion(SyntheticParams(**motion)) if signal == "motion" else None
    dev = SimMpu6050(source, clock, who_am_i=who_am_i, signal=signal)
    bus = SimI2CBus(clock, {0x68: dev})
    return SimpleNamespace(clock=clock, dev=dev, drv=Mpu6050(bus, "pl", ImuSettings(), clock.sleep))


def test_probe_names_genuine_and_clone_ids():
    assert rig().drv.probe() == "MPU-6050/6000"
    assert "clone" in rig(who_am_i=0x98).drv.probe()


def test_wrong_who_am_i_says_where_and_what_to_check():
    with pytest.raises(DeviceError) as exc:
        rig(who_am_i=0x00).drv.probe()
    msg = str(exc.value)
    assert "I2C bus 1 address 0x68" in msg and "0x00" in msg
    assert "wiring" in msg and "AD0" in msg
    assert exc.value.exit_status == EXIT_UNAVAILABLE


def test_missing_sensor_is_a_device_error_with_errno_and_hint():
    clock = ManualClock()
    driver = Mpu6050(SimI2CBus(clock, {}), "sa", ImuSettings(), clock.sleep)
    with pytest.raises(DeviceError, match=r"0x69 \(sa IMU\).*no ACK.*AD0") as exc:
        driver.probe()
    assert exc.value.errno == 6  # ENXIO, as the kernel reports a NACKed address


def test_start_writes_the_configuration_and_the_fifo_runs_at_the_sensor_rate():
    x = rig()
    x.drv.start()
    assert x.dev.regs[reg.CONFIG] == 1 and x.dev.regs[reg.SMPLRT_DIV] == 0
    assert x.dev.regs[reg.GYRO_CONFIG] == 0 and x.dev.regs[reg.ACCEL_CONFIG] == 1 << 3  # 250, 4 g
    assert x.dev.regs[reg.PWR_MGMT_1] == reg.CLKSEL_PLL_GYRO_X
    x.clock.sleep(0.05)
    count = x.drv.fifo_count()
    # 50 ms at 1027 Hz = 51.35 frames: 51 or 52 depending on phase, whole frames only
    assert count % reg.FRAME_BYTES == 0 and count // reg.FRAME_BYTES in (51, 52)
    frames: list[np.ndarray] = []
    x.drv.read_frames(count // reg.FRAME_BYTES, frames)
    n, ok = decode_counter(np.concatenate(frames))
    assert ok.all() and np.all(np.diff(n) == 1)
    # 26 block reads of 245 bits at 400 kHz take 16 ms: ~16 new frames meanwhile, no more
    assert x.drv.fifo_count() // reg.FRAME_BYTES <= 20 and not x.drv.read_overflow()


def test_overflow_is_flagged_and_reset_fifo_realigns():
    x = rig()
    x.drv.start()
    x.clock.sleep(0.2)  # 205 frames into an 85-frame FIFO
    assert x.drv.fifo_count() == reg.FIFO_SIZE  # 1024 is not whole frames: misaligned
    assert x.drv.read_overflow()
    x.drv.reset_fifo()  # reads INT_STATUS, which clears the flag
    assert not x.drv.read_overflow()
    x.clock.sleep(0.01)
    frames: list[np.ndarray] = []
    x.drv.read_frames(x.drv.fifo_count() // 12, frames)
    assert decode_counter(np.concatenate(frames))[1].all()


def test_power_cycle_is_detected():
    x = rig()
    x.drv.start()
    assert x.drv.is_running()
    x.dev.hard_reset()
    assert not x.drv.is_running()


def test_si_conversion_sees_gravity_tilted_by_gamma():
    gamma = np.radians(30)
    x = rig(signal="motion", rps=0, imbalance_rad_s2=0, vibration_std_rad_s2=0, gamma_rad=gamma)
    x.drv.start()
    x.clock.sleep(0.08)
    frames: list[np.ndarray] = []
    x.drv.read_frames(x.drv.fifo_count() // 12, frames)
    accel, gyro = to_si(np.concatenate(frames), x.drv.settings)
    want = 9.80665 * np.array([0, np.sin(gamma), np.cos(gamma)]) + x.dev.accel_bias
    # noise 400 ug/rtHz over ~500 Hz ~ 0.09 m/s^2 per sample, /sqrt(80) averaged; + 1 LSB
    np.testing.assert_allclose(accel.mean(axis=0), want, atol=0.03)
    np.testing.assert_allclose(gyro.mean(axis=0), x.dev.gyro_bias, atol=3e-4)  # ~2 LSB at 250 dps


def test_self_test_passes_a_good_part_and_fails_a_bad_one():
    for st_error, passed in ((0.03, True), (0.25, False)):
        x = rig(signal="motion", rps=0, imbalance_rad_s2=0, vibration_std_rad_s2=0)
        x.dev.st_error = st_error
        x.drv.start()
        result = x.drv.self_test()
        # responses ~5900 LSB (gyro) and ~2200 LSB (accel); noise per sample 15 and 37 LSB,
        # so the difference of two 50-sample means has sigma 3 and 7.4 LSB: 5e-4 and 3.4e-3
        np.testing.assert_allclose(result.gyro_change, st_error, atol=2.5e-3)
        np.testing.assert_allclose(result.accel_change, st_error, atol=1.5e-2)
        assert result.passed is passed


def test_self_test_refuses_clones():
    x = rig(who_am_i=0x70)
    x.drv.start()
    with pytest.raises(DeviceError, match="MPU-6500"):
        x.drv.self_test()


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"sample_rate_hz": 300.0}, "integer d in 0..255"),
        ({"sample_rate_hz": 200.0}, "aliases"),
        ({"dlpf_cfg": 0}, "DLPF off"),
        ({"address_sa": 0x68}, "share one address"),
        ({"address_sa": 0x70}, "AD0"),
        ({"gyro_fs_dps": 300}, "gyro_fs_dps"),
        ({"sa_axis": "w"}, "sa_axis"),
        ({"sample_rate_hz": 0.0}, "sample_rate_hz"),
    ],
)
def test_settings_reject_bad_values_with_the_key_and_the_fix(kwargs, words):
    with pytest.raises(UsageError, match=words):
        ImuSettings(**kwargs)


def test_settings_accept_the_scanner_defaults_and_slower_divided_rates():
    assert ImuSettings().smplrt_div == 0
    assert ImuSettings(sample_rate_hz=500.0, dlpf_cfg=2).smplrt_div == 1


def test_differentiator_keeps_the_rotation_lines_and_rejects_high_frequency_noise():
    fs = 1000.0
    t = np.arange(5000) / fs
    for f in (15.0, 25.0):
        d = angular_acceleration(np.sin(2 * np.pi * f * t), fs)[50:-50]
        # Savitzky-Golay 11/3: gain error 0.1 % at 25 Hz (see its docstring)
        assert abs(d.std() * np.sqrt(2) / (2 * np.pi * f) - 1) < 2e-3
    noise = np.random.default_rng(1).standard_normal(20000)
    central = np.gradient(noise) * fs
    # white noise: a central difference passes sqrt(1/2)/T rms, SG 11/3 0.24/T (0.34 of it)
    assert angular_acceleration(noise, fs).std() < 0.4 * central.std()


def test_bus_budget_two_sensors_at_1khz_fit_400khz_not_100khz():
    budget = bus_budget(ImuSettings())
    assert budget["payload_bytes_per_s"] == 24000
    assert 0.5 < budget["utilization"] < 0.7  # 24 payload bytes per 27-byte transaction
    assert budget["max_rate_hz_per_sensor"] > 1500
    assert bus_budget(ImuSettings(), bus_hz=100e3)["utilization"] > 1


def test_streaming_differentiator_equals_the_offline_one():
    fs = 1027.0
    x = np.random.default_rng(3).standard_normal(1000).cumsum() * 1e-3
    stream = AngularAccelerationStream(fs)
    chunks = np.split(x, [7, 30, 31, 400, 777])  # uneven batches, one of a single sample
    got = np.concatenate([stream.push(c) for c in chunks])
    want = angular_acceleration(x, fs)[5:-5]  # the interior: the stream lags by 5 samples
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)


REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "mpu6050_erm_motor_rpi"


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/real not present")
def test_twin_clips_like_a_real_mpu6050():
    """The ERM record (SOURCE.md: saturated at +-2 g) clips at -32768 and +32767 LSB exactly:
    -2.0 g and 1.99994 g. The twin, read through the driver, must clip the same way."""
    real = np.genfromtxt(
        REAL / "motor_data_20241031_040618.csv", delimiter=",", names=True, dtype=None, encoding=None
    )
    real_acc = np.stack([real["acc_x"], real["acc_z"]])
    settings = ImuSettings(accel_fs_g=2)
    clock = ManualClock()
    source = SyntheticMotion(SyntheticParams(imbalance_rad_s2=1000.0, lever_m=0.05))  # ~5 g
    dev = SimMpu6050(source, clock)
    drv = Mpu6050(SimI2CBus(clock, {0x68: dev}), "pl", settings, clock.sleep)
    drv.start()
    clock.sleep(0.08)
    frames: list[np.ndarray] = []
    drv.read_frames(drv.fifo_count() // 12, frames)
    accel_g = to_si(np.concatenate(frames), settings)[0] / 9.80665
    for lo, hi in ((accel_g.min(), accel_g.max()), (real_acc.min(), real_acc.max())):
        assert lo == pytest.approx(-2.0, abs=1e-12) and hi == pytest.approx(32767 / 16384, abs=1e-12)
    assert np.sum(accel_g[:, 1] == accel_g[:, 1].max()) > 5  # clipped runs, as in the record


@pytest.mark.parametrize("dlpf_cfg", [1, 2])
def test_twin_dlpf_delays_what_the_datasheet_says_and_keeps_its_bandwidth(dlpf_cfg):
    """The daemon subtracts DLPF_DELAY_S from sample times: the twin must delay that much (a
    0.7 ms error misplaced the SA acceleration against the pulses); −3 dB stays at the bandwidth."""
    from scipy.signal import group_delay, sos2tf, sosfreqz

    sos = dlpf_sos(dlpf_cfg, 1000.0)
    _, gd = group_delay(sos2tf(sos), w=[1.0], fs=1000.0)
    assert gd[0] / 1000.0 == pytest.approx(reg.DLPF_DELAY_S[dlpf_cfg], abs=2e-6)
    _, h = sosfreqz(sos, worN=[reg.DLPF_GYRO_BW_HZ[dlpf_cfg]], fs=1000.0)
    assert abs(h[0]) == pytest.approx(2**-0.5, rel=1e-3)  # the allpass changes no magnitude


@pytest.mark.parametrize("frames_wanted", [1, 40, 41, 80])
def test_frames_and_int_status_in_one_transfer_as_two_calls(frames_wanted):
    """read_frames_then_overflow: the INT_STATUS read rides in the last FIFO transfer (one
    round trip fewer per poll); the same frames, in order, and the same flag as read_frames
    followed by read_overflow, at each transfer boundary (40 frames fit beside the status
    pair, 42 without)."""
    x = rig()
    x.drv.start()
    x.clock.sleep(frames_wanted / 1027 + 0.002)
    frames: list[np.ndarray] = []
    have = x.drv.fifo_count() // reg.FRAME_BYTES
    assert have >= frames_wanted
    assert not x.drv.read_frames_then_overflow(frames_wanted, frames)
    n, ok = decode_counter(np.concatenate(frames))
    assert ok.all() and len(n) == frames_wanted and np.all(np.diff(n) == 1)
    x.clock.sleep(0.2)  # past the FIFO: the flag comes back with the next frames
    assert x.drv.read_frames_then_overflow(2, frames)
    assert not x.drv.read_frames_then_overflow(0, frames)  # INT_STATUS cleared by the read
