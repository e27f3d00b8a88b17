"""tvsd.rpc.client and the daemon commands of tvsctl, against a fake daemon on a real socket."""

from __future__ import annotations

import asyncio
import json
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tvsd.cli import main as cli
from tvsd.daemon.rpc import DEVICE_ERROR, STATE_ERROR, RpcError, ThreadedRpcServer
from tvsd.errors import DaemonUnavailable
from tvsd.rpc.client import (
    DEFAULT_SOCKET,
    RemoteDeviceError,
    RemoteError,
    RemoteParamsError,
    RpcClient,
    socket_path,
)

STATUS = {"state": "scanning", "rps": 25.0, "gains": {"Gp": 40.0, "Gd": 1.2}, "faults": []}


class FakeDaemon:
    """The daemon's method table, recording each call."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, dict[str, Any]]] = []

    def table(self) -> dict[str, Any]:
        def method(name: str, result: object = None) -> Any:
            async def fn(**kw: Any) -> object:
                self.calls.append((name, kw))
                return result if result is not None else {"ok": True}

            return fn

        async def status() -> dict[str, object]:
            self.calls.append(("status", {}))
            return STATUS

        async def speed(rps: float) -> dict[str, float]:
            if rps > 100:
                raise RpcError(DEVICE_ERROR, f"motor driver refused {rps:g} rev/s: limit is 100")
            self.calls.append(("speed", {"rps": rps}))
            return {"rps": rps}

        async def aim(phi_deg: float, gamma_deg: float) -> dict[str, float]:
            self.calls.append(("aim", {"phi_deg": phi_deg, "gamma_deg": gamma_deg}))
            return {"phi_deg": phi_deg, "gamma_deg": gamma_deg}

        async def aim_xyz(x: float, y: float, z: float) -> dict[str, float]:
            self.calls.append(("aim_xyz", {"x": x, "y": y, "z": z}))
            return {"x": x, "y": y, "z": z}

        async def gains_set(Gp: float, Gd: float, Gr: float, G0: float) -> dict[str, float]:
            self.calls.append(("gains_set", {"Gp": Gp, "Gd": Gd, "Gr": Gr, "G0": G0}))
            return {"Gp": Gp, "Gd": Gd, "Gr": Gr, "G0": G0}

        async def scan_stop() -> None:
            raise RpcError(STATE_ERROR, "not scanning")

        async def faults_list() -> list[dict[str, object]]:
            self.calls.append(("faults_list", {}))
            return [{"code": "E_STALL", "count": 2}, {"code": "E_IMU", "count": 1}]

        names = ("scan_start", "gains_get", "record_start", "record_stop", "faults_clear", "shutdown")
        return {
            **{n: method(n) for n in names},
            "status": status,
            "speed": speed,
            "aim": aim,
            "aim_xyz": aim_xyz,
            "gains_set": gains_set,
            "scan_stop": scan_stop,
            "faults_list": faults_list,
        }


@pytest.fixture
def short_dir() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="tvs") as tmp:  # sun_path allows 107 bytes only
        yield Path(tmp)


@pytest.fixture
def daemon(short_dir: Path) -> Iterator[tuple[ThreadedRpcServer, FakeDaemon]]:
    fake = FakeDaemon()
    with ThreadedRpcServer(short_dir / "tvsd.sock", fake.table()) as t:
        yield t, fake


@pytest.fixture(autouse=True)
def daemon_commands(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(cli.COMMANDS, "daemon", "tvsd.cli.daemon_cmds")
    monkeypatch.delenv("TVSD_SOCKET", raising=False)


def tvsctl(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = cli.main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


# --- the client ---------------------------------------------------------------------------------


def test_socket_path_precedence(monkeypatch: pytest.MonkeyPatch) -> None:
    assert socket_path(None) == DEFAULT_SOCKET == Path("/run/tvsd/tvsd.sock")
    monkeypatch.setenv("TVSD_SOCKET", "/tmp/env.sock")
    assert socket_path(None) == Path("/tmp/env.sock")
    assert socket_path(Path("/tmp/arg.sock")) == Path("/tmp/arg.sock")


def test_no_daemon_is_daemon_unavailable_with_exit_status_3(short_dir: Path) -> None:
    path = short_dir / "tvsd.sock"
    with pytest.raises(DaemonUnavailable) as info:
        RpcClient(path).call("status")
    assert info.value.exit_status == 3
    assert str(info.value) == (
        f"tvsd is not running (no socket at {path}): start it with `make run` or "
        "`systemctl start tvsd`, or give --socket"
    )


def test_refused_socket_is_daemon_unavailable(short_dir: Path) -> None:
    import socket

    path = short_dir / "dead.sock"
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(path))  # the file of a daemon that died
    s.close()
    with pytest.raises(DaemonUnavailable, match="tvsd is not running"):
        RpcClient(path).call("status")


def test_calls_and_error_replies_map_to_exit_statuses(daemon: tuple[ThreadedRpcServer, FakeDaemon]) -> None:
    t, _ = daemon
    with RpcClient(t.path) as client:
        assert client.call("status") == STATUS
        assert client.call("speed", rps=10) == {"rps": 10.0}
        with pytest.raises(RemoteParamsError, match="speed: parameter 'rps' must be a number") as e2:
            client.call("speed", rps="fast")
        with pytest.raises(RemoteDeviceError, match="limit is 100") as e3:
            client.call("speed", rps=500)
        with pytest.raises(RemoteError, match="not scanning") as e1:
            client.call("scan_stop")
        with pytest.raises(RemoteError, match="unknown method 'warp'") as e_missing:
            client.call("warp")
        assert client.call("status") == STATUS  # the connection survives error replies
    assert (e2.value.exit_status, e3.value.exit_status, e1.value.exit_status) == (2, 3, 1)
    assert isinstance(e2.value, ValueError) and isinstance(e3.value, OSError)
    assert e_missing.value.exit_status == 1 and "status" in e_missing.value.data  # type: ignore[operator]
    assert e3.value.code == DEVICE_ERROR


def test_subscribe_yields_params_until_the_daemon_closes(
    daemon: tuple[ThreadedRpcServer, FakeDaemon],
) -> None:
    t, _ = daemon

    async def publish() -> None:
        while t.server.stats["requests"] < 1:  # until the subscribe request has been handled
            await asyncio.sleep(0.001)
        for i in range(3):
            t.server.publish("points", {"i": i})
        await asyncio.sleep(0.05)
        await t.server.close()

    fut = asyncio.run_coroutine_threadsafe(publish(), t.loop)
    with RpcClient(t.path) as client:
        got = list(client.subscribe("points"))
    fut.result(5)
    assert got == [{"i": 0}, {"i": 1}, {"i": 2}]


def test_subscription_is_live_when_subscribe_returns(daemon: tuple[ThreadedRpcServer, FakeDaemon]) -> None:
    t, _ = daemon
    with RpcClient(t.path) as client:
        stream = client.subscribe("points")
        for i in range(3):  # from this (non-loop) thread, as the control thread does
            t.server.publish_threadsafe("points", {"i": i})
        assert [next(stream) for _ in range(3)] == [{"i": 0}, {"i": 1}, {"i": 2}]


# --- tvsctl commands ----------------------------------------------------------------------------


def test_status_json_prints_the_object(
    daemon: tuple[ThreadedRpcServer, FakeDaemon], capsys: pytest.CaptureFixture[str]
) -> None:
    t, _ = daemon
    status, out, err = tvsctl(capsys, "status", "--json", "--socket", str(t.path))
    assert (status, err) == (0, "")
    assert json.loads(out) == STATUS


def test_status_table_flattens_nested_objects(
    daemon: tuple[ThreadedRpcServer, FakeDaemon],
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    t, _ = daemon
    monkeypatch.setenv("TVSD_SOCKET", str(t.path))  # no --socket: the environment names it
    status, out, _ = tvsctl(capsys, "status")
    assert status == 0
    lines = {line.split()[0]: line.split()[1] for line in out.splitlines()}
    assert lines == {"state": "scanning", "rps": "25", "gains.Gp": "40", "gains.Gd": "1.2", "faults": "[]"}


@pytest.mark.parametrize(
    ("argv", "call"),
    [
        (["speed", "12.5"], ("speed", {"rps": 12.5})),
        (["scan", "start"], ("scan_start", {})),
        (["aim", "--phi-deg", "10", "--gamma-deg", "-5"], ("aim", {"phi_deg": 10.0, "gamma_deg": -5.0})),
        (["aim", "--xyz", "1", "2", "3"], ("aim_xyz", {"x": 1.0, "y": 2.0, "z": 3.0})),
        (["gains"], ("gains_get", {})),
        (["gains", "--set", "40,1.2,0.5,0"], ("gains_set", {"Gp": 40.0, "Gd": 1.2, "Gr": 0.5, "G0": 0.0})),
        (["record", "start"], ("record_start", {})),
        (["record", "stop"], ("record_stop", {})),
        (["faults"], ("faults_list", {})),
        (["faults", "--clear"], ("faults_clear", {})),
        (["shutdown"], ("shutdown", {})),
    ],
)
def test_each_command_calls_its_method(
    daemon: tuple[ThreadedRpcServer, FakeDaemon],
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    call: tuple[str, dict[str, Any]],
) -> None:
    t, fake = daemon
    status, out, err = tvsctl(capsys, *argv, "--socket", str(t.path))
    assert (status, err) == (0, "")
    assert fake.calls == [call]
    assert out.strip()


def test_faults_table(
    daemon: tuple[ThreadedRpcServer, FakeDaemon], capsys: pytest.CaptureFixture[str]
) -> None:
    t, _ = daemon
    _, out, _ = tvsctl(capsys, "faults", "--socket", str(t.path))
    assert out.split("\n")[0].split() == ["code", "count"] and "E_STALL" in out


@pytest.mark.parametrize(
    ("argv", "status", "words"),
    [
        (["speed", "500"], 3, "limit is 100"),
        (["scan", "stop"], 1, "not scanning"),
        (["aim", "--phi-deg", "10"], 2, "give --phi-deg DEG and --gamma-deg DEG together"),
        (["aim", "--phi-deg", "1", "--gamma-deg", "2", "--xyz", "1", "2", "3"], 2, "(not both)"),
        (["gains", "--set", "1,2,3"], 2, "give four numbers Gp,Gd,Gr,G0"),
        (["gains", "--set", "1,x,3,4"], 2, "Gd is 'x', not a number"),
        (["gains", "--set", "1,nan,3,4"], 2, "give a finite number"),
        (["points", "--count", "0"], 2, "--count 0: give at least 1"),
    ],
)
def test_failures_are_one_line_with_their_exit_status(
    daemon: tuple[ThreadedRpcServer, FakeDaemon],
    capsys: pytest.CaptureFixture[str],
    argv: list[str],
    status: int,
    words: str,
) -> None:
    t, _ = daemon
    got, _, err = tvsctl(capsys, *argv, "--socket", str(t.path))
    assert got == status
    assert err.startswith("tvsctl: ") and words in err and err.count("\n") == 1, err


def test_no_daemon_from_the_command_line(short_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = tvsctl(capsys, "status", "--socket", str(short_dir / "none.sock"))
    assert (status, out) == (3, "")
    assert err == f"tvsctl: tvsd is not running (no socket at {short_dir / 'none.sock'}): start it with " \
        "`make run` or `systemctl start tvsd`, or give --socket\n"  # fmt: skip


def test_points_prints_count_points_then_exits(
    daemon: tuple[ThreadedRpcServer, FakeDaemon], capsys: pytest.CaptureFixture[str]
) -> None:
    t, _ = daemon

    async def feed() -> None:  # a scanner producing batches of points, whoever listens
        for i in range(1000):
            t.server.publish("points", [{"x": float(i), "y": 0.5}, {"x": float(i), "y": 1.5}])
            await asyncio.sleep(0.002)

    task = asyncio.run_coroutine_threadsafe(feed(), t.loop)
    try:
        status, out, err = tvsctl(capsys, "points", "--count", "3", "--json", "--socket", str(t.path))
    finally:
        task.cancel()
    assert (status, err) == (0, "")
    points = [json.loads(line) for line in out.splitlines()]
    assert len(points) == 3 and all(set(p) == {"x", "y"} for p in points)


@pytest.mark.parametrize("argv", [["speed", "nan"], ["speed", "inf"], ["aim", "--xyz", "inf", "0", "0"]])
def test_a_non_finite_number_is_refused_by_tvsctl_itself(
    daemon: tuple[ThreadedRpcServer, FakeDaemon], capsys: pytest.CaptureFixture[str], argv: list[str]
) -> None:
    """`tvsctl speed nan` sent NaN (not JSON); tvsd's -32700 came back without our id and tvsctl
    waited 5 s to say "tvsd did not answer 'speed' ... it may be stuck" (exit 3)."""
    t, _ = daemon
    status, _, err = tvsctl(capsys, *argv, "--socket", str(t.path))
    assert status == 2 and "give a finite number" in err and err.count("\n") == 1, err


def test_an_error_the_daemon_could_not_address_to_a_call_ends_it(
    daemon: tuple[ThreadedRpcServer, FakeDaemon],
) -> None:
    """A request tvsd cannot read gets an error with id null: it is this call's answer, not a
    5 s wait for one that never comes."""
    t, _ = daemon
    with RpcClient(t.path, timeout=5.0) as client:
        client._connect().sendall(b"not json\n")  # as a client whose line tvsd cannot read
        with pytest.raises(RemoteError, match="not JSON"):
            client.call("status")


def test_the_points_stream_ends_with_a_message_when_its_socket_closes_under_the_read() -> None:
    """tvsctl closes its connection on the way out while the points reader thread is still in
    recv(): OSError EBADF escaped that thread as a traceback on stderr (CI, beside a busy loop).
    The reader ends with DaemonUnavailable, which the caller sees if it is still waiting."""
    import errno

    from tvsd.cli.point_wait import stream_points
    from tvsd.errors import DaemonUnavailable

    class ClosedUnderRead:
        def subscribe(self, topic: str):
            raise OSError(errno.EBADF, "Bad file descriptor")
            yield  # a generator, as RpcClient.subscribe

    with pytest.raises(DaemonUnavailable, match="points stream ended"):
        next(stream_points(ClosedUnderRead(), 1, timeout_s=0.5))  # type: ignore[arg-type]
