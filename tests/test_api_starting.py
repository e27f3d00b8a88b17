"""A command while the daemon's devices are still coming up (issue 13): `tvsd --sil &` then
`tvsctl speed 25` at once was refused ("the devices are coming up: retry in a second"). It now
waits for the devices (at most api.STARTING_WAIT_S, under tvsctl's 5 s call timeout) and is carried
out; a start that takes longer is answered as the state is, with what to look at. The daemon is a
stand-in with the state and the one command the method uses: what is tested is the API's wait."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

from tvsd.daemon import api as api_mod
from tvsd.daemon.api import Api
from tvsd.daemon.rpc import STATE_ERROR, RpcError
from tvsd.daemon.state import DaemonState


def fake_daemon() -> SimpleNamespace:
    d = SimpleNamespace(state=DaemonState.STARTING, speeds=[])
    d.cfg = SimpleNamespace(daemon=SimpleNamespace(max_rps=40.0))
    d.set_speed = d.speeds.append
    return d


def test_speed_during_start_waits_for_the_devices_and_is_carried_out() -> None:
    d = fake_daemon()

    async def main() -> dict:
        async def up() -> None:
            await asyncio.sleep(0.3)  # the devices come up
            d.state = DaemonState.IDLE

        task = asyncio.create_task(up())
        reply = await Api(d).api_speed(25.0)  # type: ignore[arg-type]
        await task
        return reply

    assert asyncio.run(main()) == {"rps_setpoint": 25.0}
    assert d.speeds == [25.0]


def test_speed_during_a_start_that_never_ends_is_refused_after_the_wait(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(api_mod, "STARTING_WAIT_S", 0.2)
    d = fake_daemon()
    with pytest.raises(RpcError) as err:
        asyncio.run(Api(d).api_speed(25.0))  # type: ignore[arg-type]
    assert err.value.code == STATE_ERROR and "still coming up after 0.2 s" in str(err.value)
    assert d.speeds == []


def test_speed_during_start_that_ends_in_a_fault_is_refused_as_a_fault() -> None:
    d = fake_daemon()

    async def main() -> None:
        async def faulted() -> None:
            await asyncio.sleep(0.1)
            d.state = DaemonState.FAULT

        task = asyncio.create_task(faulted())
        try:
            await Api(d).api_speed(25.0)  # type: ignore[arg-type]
        finally:
            await task

    with pytest.raises(RpcError) as err:
        asyncio.run(main())
    assert err.value.code == STATE_ERROR and "faults_clear" in str(err.value)
