"""systemd notify protocol against a real AF_UNIX datagram socket standing in for systemd."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator

import pytest

from tvsd.daemon.notify import Notifier, socket_address


def _receive(sock: socket.socket) -> bytes:
    sock.settimeout(2.0)
    return sock.recv(4096)


@pytest.fixture
def path_socket(tmp_path) -> Iterator[tuple[str, socket.socket]]:
    path = str(tmp_path / "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    yield path, sock
    sock.close()


@pytest.fixture
def abstract_socket() -> Iterator[tuple[str, socket.socket]]:
    name = f"tvsd-test-notify-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(b"\0" + name.encode())
    yield "@" + name, sock
    sock.close()


@pytest.mark.parametrize("which", ["path_socket", "abstract_socket"])
def test_exact_messages_reach_the_manager(which, request):
    address, manager = request.getfixturevalue(which)
    n = Notifier({"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "2000000"}, pid=123)
    assert n.enabled
    assert n.ready()
    assert _receive(manager) == b"READY=1"
    assert n.status("scanning at 25 rev/s")
    assert _receive(manager) == b"STATUS=scanning at 25 rev/s"
    assert n.watchdog()
    assert _receive(manager) == b"WATCHDOG=1"
    assert n.stopping()
    assert _receive(manager) == b"STOPPING=1"
    n.close()


def test_ready_with_status_is_one_datagram_and_newlines_cannot_inject_keys(path_socket):
    address, manager = path_socket
    n = Notifier({"NOTIFY_SOCKET": address}, pid=1)
    n.ready("up\nREADY=0")
    assert _receive(manager) == b"READY=1\nSTATUS=up READY=0"


def test_watchdog_interval_is_half_of_watchdog_usec(path_socket):
    address, _ = path_socket
    n = Notifier({"NOTIFY_SOCKET": address, "WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "77"}, pid=77)
    assert n.watchdog_interval_s == pytest.approx(1.0)


@pytest.mark.parametrize(
    "env",
    [
        {"WATCHDOG_USEC": "2000000", "WATCHDOG_PID": "78"},  # meant for another process
        {"WATCHDOG_USEC": "0"},
        {"WATCHDOG_USEC": "soon"},
        {},
    ],
)
def test_no_watchdog_when_not_asked_for_this_pid(path_socket, env):
    address, manager = path_socket
    n = Notifier({"NOTIFY_SOCKET": address, **env}, pid=77)
    assert n.watchdog_interval_s is None
    assert not n.watchdog()
    manager.setblocking(False)
    with pytest.raises(BlockingIOError):  # nothing was sent
        manager.recv(4096)


def test_noop_outside_systemd():
    n = Notifier({}, pid=1)
    assert not n.enabled and n.watchdog_interval_s is None
    assert not any([n.ready(), n.status("x"), n.watchdog(), n.stopping()])


def test_vanished_socket_is_reported_not_raised(tmp_path):
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "gone")}, pid=1)
    assert n.enabled and not n.ready()  # ENOENT: logged once, returns False


@pytest.mark.parametrize(
    "value,expected",
    [("/run/systemd/notify", "/run/systemd/notify"), ("@x/y", b"\0x/y"), ("vsock:2:9", None), ("@", None)],
)
def test_socket_address(value, expected):
    assert socket_address(value) == expected
