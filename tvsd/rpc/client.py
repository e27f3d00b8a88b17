"""Blocking JSON-RPC 2.0 client of tvsd's Unix socket, for tvsctl (protocol: tvsd/rpc/protocol.py).

Error replies become TvsdError subclasses carrying the daemon's message, so tvsctl prints one line
and exits with the documented status: invalid params → 2, device error → 3, anything else → 1.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import socket
from collections import deque
from collections.abc import Iterator
from pathlib import Path

from tvsd.errors import DaemonUnavailable, DeviceError, TvsdError, UsageError
from tvsd.rpc.protocol import DEVICE_ERROR, INVALID_PARAMS

DEFAULT_SOCKET = Path("/run/tvsd/tvsd.sock")
ENV_SOCKET = "TVSD_SOCKET"


def socket_path(arg: Path | None) -> Path:
    """--socket, else $TVSD_SOCKET, else DEFAULT_SOCKET."""
    if arg is not None:
        return Path(arg)
    env = os.environ.get(ENV_SOCKET)
    return Path(env) if env else DEFAULT_SOCKET


class RemoteError(TvsdError):
    """tvsd answered a call with a JSON-RPC error (exit status 1 unless a subclass says otherwise)."""

    def __init__(self, code: int, message: str, data: object = None) -> None:
        super().__init__(message)
        self.code = code
        self.data = data


class RemoteParamsError(RemoteError, UsageError):
    """tvsd refused the call's parameters (exit status 2)."""


class RemoteDeviceError(RemoteError, DeviceError):
    """tvsd could not do it because a device failed (exit status 3)."""


def remote_error(code: int, message: str, data: object = None) -> RemoteError:
    cls = {INVALID_PARAMS: RemoteParamsError, DEVICE_ERROR: RemoteDeviceError}.get(code, RemoteError)
    return cls(code, message, data)


def _unavailable(path: Path) -> DaemonUnavailable:
    return DaemonUnavailable(
        f"tvsd is not running (no socket at {path}): start it with `make run` or "
        "`systemctl start tvsd`, or give --socket"
    )


class RpcClient:
    """One connection to tvsd; connects on the first call."""

    def __init__(self, path: Path, timeout: float = 5.0) -> None:
        self.path = Path(path)
        self.timeout = timeout
        self._sock: socket.socket | None = None
        self._buf = b""
        self._ids = itertools.count(1)
        self._notes: deque[dict[str, object]] = deque()

    def __enter__(self) -> RpcClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _connect(self) -> socket.socket:
        if self._sock is not None:
            return self._sock
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.settimeout(self.timeout)
        try:
            sock.connect(str(self.path))
        except (FileNotFoundError, ConnectionRefusedError) as exc:
            sock.close()
            raise _unavailable(self.path) from exc
        except PermissionError as exc:
            sock.close()
            raise DaemonUnavailable(
                f"permission denied on {self.path}: join the socket's group (e.g. `sudo usermod -aG tvsd "
                "$USER`, then log in again) or run tvsctl as root"
            ) from exc
        except OSError as exc:  # e.g. a path too long for a Unix socket, or not a socket
            sock.close()
            raise DaemonUnavailable(f"cannot connect to tvsd at {self.path}: {exc.strerror or exc}") from exc
        self._sock = sock
        return sock

    def call(self, method: str, **params: object) -> object:
        """Call `method` with params by name; returns its result or raises a RemoteError."""
        for name, value in params.items():
            if isinstance(value, float) and not math.isfinite(value):  # NaN/Infinity are not JSON
                raise UsageError(f"{method}: {name} = {value}: give a finite number")
        sock = self._connect()
        req_id = next(self._ids)
        req = {"jsonrpc": "2.0", "id": req_id, "method": method, "params": params}
        try:
            sock.sendall(json.dumps(req, separators=(",", ":"), allow_nan=False).encode() + b"\n")
            while True:
                msg = self._read_message()
                if msg.get("id") == req_id and ("result" in msg or "error" in msg):
                    break
                if "id" in msg and msg["id"] is None and "error" in msg:
                    break  # tvsd could not read our line as a request: its error is ours
                if "method" in msg and "id" not in msg:
                    self._notes.append(msg)
        except TimeoutError as exc:
            self.close()
            raise DaemonUnavailable(
                f"tvsd did not answer {method!r} within {self.timeout:g} s on {self.path}: "
                "it may be stuck; see `journalctl -u tvsd`"
            ) from exc
        if "error" in msg:
            err = msg["error"]
            if not isinstance(err, dict):
                raise RemoteError(0, f"tvsd sent a malformed error for {method!r}: {err!r}")
            code = err.get("code")
            return_code = code if isinstance(code, int) else 0
            raise remote_error(return_code, str(err.get("message", "error without message")), err.get("data"))
        return msg["result"]

    def subscribe(self, topic: str) -> Iterator[object]:
        """Subscribe to `topic` now; the iterator yields each notification's params until tvsd closes."""
        self.call("subscribe", topic=topic)
        return self._notifications(topic)

    def _notifications(self, topic: str) -> Iterator[object]:
        sock = self._connect()
        sock.settimeout(None)  # a stream may be quiet for long; Ctrl-C stops tvsctl
        while True:
            while self._notes:
                note = self._notes.popleft()
                if note.get("method") == topic:
                    yield note.get("params")
            try:
                msg = self._read_message()
            except DaemonUnavailable:
                return
            if msg.get("method") == topic:
                yield msg.get("params")

    def _read_message(self) -> dict[str, object]:
        """The next JSON object from the socket; DaemonUnavailable when the daemon closed it."""
        assert self._sock is not None
        while b"\n" not in self._buf:
            try:
                chunk = self._sock.recv(65536)
            except ConnectionError as exc:
                self.close()
                raise DaemonUnavailable(f"tvsd closed the connection on {self.path}: {exc}") from exc
            if not chunk:
                self.close()
                raise DaemonUnavailable(f"tvsd closed the connection on {self.path} (did it stop?)")
            self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        try:
            msg = json.loads(line)
        except ValueError as exc:
            raise TvsdError(f"tvsd sent a line that is not JSON ({exc}): {line[:80]!r}") from exc
        if not isinstance(msg, dict):
            raise TvsdError(f"tvsd sent JSON that is not an object: {line[:80]!r}")
        return msg
