"""A bad parameter gets -32602 in every state (found by scripts/api_fuzz.py on the installed wheel):
`speed 1e6` to a faulted daemon answered "clear the fault first" (-32002), and after the clear the
same request was -32602; `record_window -1` said "start a recording"; `identify` with bad kinds
said the same as the state. A client cannot fix a request it is told is fine. The daemon is a
stand-in with the state and what each method touches: what is tested is the order of the checks."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

from tvsd.config import load_config
from tvsd.daemon.api import Api
from tvsd.daemon.rpc import INVALID_PARAMS, STATE_ERROR, RpcError
from tvsd.daemon.state import DaemonState


def faulted_daemon() -> SimpleNamespace:
    cfg = load_config(params="default")
    d = SimpleNamespace(state=DaemonState.FAULT, cfg=cfg, recording=None, speeds=[])
    d.runner = SimpleNamespace(ring_size=60000)
    d.set_speed = d.speeds.append
    return d


@pytest.mark.parametrize(
    ("method", "kwargs"),
    [
        ("api_speed", {"rps": 1e6}),
        ("api_speed", {"rps": float("nan")}),
        ("api_record_window", {"seconds": -1.0}),
        ("api_record_window", {"seconds": 1e300}),
        ("api_identify", {"kinds": ["nope"]}),
        ("api_identify", {"seconds": -5.0}),
    ],
)
def test_a_bad_parameter_is_invalid_params_even_in_a_fault(method: str, kwargs: dict) -> None:
    d = faulted_daemon()
    with pytest.raises(RpcError) as err:
        asyncio.run(getattr(Api(d), method)(**kwargs))  # type: ignore[arg-type]
    assert err.value.code == INVALID_PARAMS, err.value.message
    assert d.speeds == []


@pytest.mark.parametrize("seconds", [-1.0, 0.5, 1e300, float("nan")])
@pytest.mark.parametrize("state", ["no IMU", "turning"])
def test_a_bad_calibration_length_is_invalid_params_whatever_the_imu_and_the_rotor(
    state: str, seconds: float
) -> None:
    """`imu_calibrate` judged the daemon first: `seconds -1` with no IMU running (devices.imu off)
    or with the aperture turning said -32002 ("no IMU", "stop it"), at rest with an IMU -32602."""

    async def calibrate(seconds: float) -> dict:
        raise AssertionError("a refused request must not calibrate")

    d = faulted_daemon()
    d.state = DaemonState.IDLE
    d.imu = None if state == "no IMU" else SimpleNamespace(calibrate=calibrate)
    d.measured_rps = 25.0 if state == "turning" else 0.0
    with pytest.raises(RpcError) as err:
        asyncio.run(Api(d).api_imu_calibrate(seconds))  # type: ignore[arg-type]
    assert err.value.code == INVALID_PARAMS, err.value.message
    assert "imu.calibrate_max_s" in err.value.message


def test_a_moving_sensor_at_calibration_is_exit_1_not_a_device_fault() -> None:
    """`tvsctl calibrate-imu` on the installed wheel, right after the motor stopped: "pl IMU is
    moving" came back as a device error (-32001), which tvsctl turns into exit 3 ("a device is
    unreachable"); the README's exit table says 1 (the command ran, the result is a refusal)."""
    from tvsd.errors import EXIT_FAILURE
    from tvsd.hw.imu_calibration import CalibrationRefused
    from tvsd.rpc.client import remote_error

    async def calibrate(seconds: float) -> dict:
        raise CalibrationRefused("pl IMU is moving: gyro spread [0.887, 0.071, 0.072] deg/s")

    d = faulted_daemon()
    d.state, d.measured_rps, d.imu = DaemonState.IDLE, 0.0, SimpleNamespace(calibrate=calibrate)
    with pytest.raises(RpcError) as err:
        asyncio.run(Api(d).api_imu_calibrate(2.0))  # type: ignore[arg-type]
    assert err.value.code == STATE_ERROR and "is moving" in err.value.message
    assert remote_error(err.value.code, err.value.message).exit_status == EXIT_FAILURE
