"""`tvsctl speed 0` then `tvsctl calibrate-imu` (found by branch newuser): the rotor still ramps
down, and the daemon refuses a calibration above 0.05 rev/s. tvsctl waits for a rotor commanded
to 0 to stop (bounded), and never for one still driven."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tvsd.cli import daemon_cmds
from tvsd.cli.main import main
from tvsd.daemon.rpc import STATE_ERROR, RpcError, ThreadedRpcServer
from tvsd.rpc.client import RpcClient


class SpinningDown:
    """A stand-in daemon: the rotor's speed falls by `step` rev/s per status call, from `rps`."""

    def __init__(self, rps: float, setpoint: float, step: float) -> None:
        self.rps, self.setpoint, self.step = rps, setpoint, step
        self.calibrated_at: list[float] = []

    def table(self) -> dict[str, Any]:
        async def status() -> dict[str, object]:
            self.rps = max(self.rps - self.step, self.setpoint)
            return {"state": "idle", "rps": self.rps, "rps_setpoint": self.setpoint, "faults": []}

        async def imu_calibrate(seconds: float) -> dict[str, object]:
            self.calibrated_at.append(self.rps)
            if abs(self.rps) > 0.05:  # as tvsd.daemon.api.api_imu_calibrate
                raise RpcError(STATE_ERROR, "the aperture is turning: stop it (tvsctl speed 0)")
            return {"file": "x.json"}

        return {"status": status, "imu_calibrate": imu_calibrate}


@pytest.fixture
def short_dir() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="tvs") as tmp:  # sun_path allows 107 bytes only
        yield Path(tmp)


def _calibrate(fake: SpinningDown, sock: Path) -> int:
    with ThreadedRpcServer(sock, fake.table()):
        return main(["calibrate-imu", "--socket", str(sock), "--json"])


def test_waits_for_a_rotor_commanded_to_stop(short_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fake = SpinningDown(rps=5.0, setpoint=0.0, step=1.0)  # 5 status calls (4 polls, 0.8 s) to rest
    assert _calibrate(fake, short_dir / "s.sock") == 0  # before: 1, "the aperture is turning"
    assert fake.calibrated_at == [0.0]
    assert "waiting for the rotor to stop" in capsys.readouterr().err


def test_a_driven_rotor_is_not_waited_for(short_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fake = SpinningDown(rps=25.0, setpoint=25.0, step=0.0)
    assert _calibrate(fake, short_dir / "s.sock") == 1
    assert fake.calibrated_at == [25.0]
    assert "the aperture is turning" in capsys.readouterr().err


def test_the_wait_is_bounded(short_dir: Path) -> None:
    fake = SpinningDown(rps=5.0, setpoint=0.0, step=0.0)  # a rotor that never stops
    sock = short_dir / "s.sock"
    with ThreadedRpcServer(sock, fake.table()), RpcClient(sock) as client:
        start = time.monotonic()
        daemon_cmds._wait_for_rest(client, wait_s=0.3, poll_s=0.01)
        assert 0.3 <= time.monotonic() - start < 5.0  # the bound, plus a loaded machine's slack
    assert daemon_cmds.REST_WAIT_S >= 2 * 7.0  # twice the longest ramp down (60 rev/s at 10 rev/s², +1 s)
