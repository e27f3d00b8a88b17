"""JSON-RPC 2.0 over a Unix socket: newline-delimited JSON, one object (or batch array) per line.

The daemon hands `RpcServer` a table of ``async def`` methods; the server checks each call's params
against the method's signature and type hints (float/int/str/bool/list/dict) before calling it, so a
method body only sees well-typed arguments. Params may come by name (object) or by position (array).

Error codes (``error.code`` of a reply):

====== ================ =====================================================================
code   name             meaning
====== ================ =====================================================================
-32700 PARSE_ERROR      the line is not JSON (NaN/Infinity are refused too); id is null
-32600 INVALID_REQUEST  valid JSON but not a request, or a line longer than ``max_message``
                        (that connection is then closed; the daemon keeps serving the others)
-32601 METHOD_NOT_FOUND ``error.data`` lists the methods offered
-32602 INVALID_PARAMS   the message names the parameter, what was seen and what is expected
-32603 INTERNAL_ERROR   a method raised something unexpected: a bug, logged with its traceback
-32001 DEVICE_ERROR     the scanner (MCU, motor, IMU, laser) refused or failed the request
-32002 STATE_ERROR      the request does not fit the daemon's state (e.g. aim while not scanning)
====== ================ =====================================================================

Built-in methods: ``subscribe(topic)`` and ``unsubscribe(topic)``. `RpcServer.publish` pushes
``{"jsonrpc": "2.0", "method": topic, "params": ...}`` to every client subscribed to ``topic``. It
never blocks: each client has a bounded queue drained by its own task, and a notification that
finds the queue full is dropped and counted (``stats["dropped_notifications"]``) — a slow
``tvsctl points`` must not slow the scanner. Call ``publish`` from the event-loop thread; from the
control thread use ``server.publish_threadsafe(topic, params)``.

Requests of one connection are handled in order; a batch's requests run concurrently.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import inspect
import json
import logging
import math
import os
import stat
import tempfile
import threading
import time
import types
import typing
from collections.abc import Awaitable, Callable, Collection, Mapping
from pathlib import Path
from typing import Any

from tvsd.errors import EXIT_FAILURE, EXIT_USAGE, TvsdError

log = logging.getLogger(__name__)

PARSE_ERROR = -32700
INVALID_REQUEST = -32600
METHOD_NOT_FOUND = -32601
INVALID_PARAMS = -32602
INTERNAL_ERROR = -32603
DEVICE_ERROR = -32001
STATE_ERROR = -32002

Method = Callable[..., Awaitable[object]]

SOCKET_PATH_MAX = 107  # sun_path is 108 bytes on Linux, NUL included
_BUILTINS = ("subscribe", "unsubscribe")


class RpcError(Exception):
    """Raised by a method to reply with a JSON-RPC error instead of a result."""

    def __init__(self, code: int, message: str, data: object | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.message = message
        self.data = data

    def to_json(self) -> dict[str, object]:
        err: dict[str, object] = {"code": self.code, "message": self.message}
        if self.data is not None:
            err["data"] = self.data
        return err


class SocketPathError(TvsdError, OSError):
    """The socket path cannot be used (too long, not a socket, directory missing or not writable)."""

    exit_status = EXIT_USAGE


class DaemonAlreadyRunning(TvsdError, FileExistsError):
    """Another daemon answers on the socket."""

    exit_status = EXIT_FAILURE


# --- params --------------------------------------------------------------------------------------

_KINDS: dict[type, tuple[str, tuple[type, ...]]] = {
    float: ("a number", (int, float)),
    int: ("an integer", (int,)),
    str: ("a string", (str,)),
    bool: ("true or false", (bool,)),
    list: ("an array", (list,)),
    dict: ("an object", (dict,)),
}


def _json_type(value: object) -> str:
    names = {bool: "boolean", int: "integer", float: "number", str: "string", list: "array", dict: "object"}
    return "null" if value is None else names.get(type(value), type(value).__name__)


def _seen(value: object) -> str:
    text = json.dumps(value)
    return f"{_json_type(value)} {text if len(text) <= 40 else text[:37] + '...'}"


@dataclasses.dataclass(frozen=True)
class _Param:
    name: str
    hint: object  # a type, a union of types, or None when not checkable
    required: bool

    def describe(self) -> str:
        return f"{self.name}: {_hint_name(self.hint)}" if self.hint is not None else self.name


def _hint_name(hint: object) -> str:
    if isinstance(hint, type):
        return hint.__name__
    return str(hint).replace("typing.", "")


def _plain_types(hint: object) -> tuple[type, ...] | None:
    """The checkable base types of a hint (``float | None`` → (float, NoneType)), or None."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        parts = [_plain_types(a) for a in typing.get_args(hint)]
        if any(p is None for p in parts):
            return None
        return tuple(t for p in parts if p is not None for t in p)
    if hint is type(None):
        return (type(None),)
    base = origin if origin is not None else hint
    return (base,) if base in _KINDS else None


class _Signature:
    """What a method accepts, read once from its signature and type hints."""

    def __init__(self, name: str, fn: Method) -> None:
        self.name = name
        sig = inspect.signature(fn)
        try:
            hints = typing.get_type_hints(fn)
        except Exception:  # unresolvable annotations: check arity only
            hints = {}
        self.params: list[_Param] = []
        self.var_kw = False
        for p in sig.parameters.values():
            if p.kind in (p.VAR_POSITIONAL, p.POSITIONAL_ONLY):
                raise ValueError(
                    f"method {name!r}: parameter {p.name!r} cannot be given by name; use plain parameters"
                )
            if p.kind is p.VAR_KEYWORD:
                self.var_kw = True
            else:
                types_ = _plain_types(hints.get(p.name))
                self.params.append(
                    _Param(p.name, hints.get(p.name) if types_ else None, p.default is p.empty)
                )

    def expected(self) -> str:
        return ", ".join(p.describe() for p in self.params) or "no parameters"

    def bind(self, params: object) -> dict[str, Any]:
        """Keyword arguments for the method, or RpcError(INVALID_PARAMS) naming the bad parameter."""
        by_name = {p.name: p for p in self.params}
        if params is None:
            given: dict[str, Any] = {}
        elif isinstance(params, list):
            if len(params) > len(self.params):
                raise self._error(
                    f"takes {len(self.params)} parameter(s) ({self.expected()}), got {len(params)}"
                )
            given = {p.name: v for p, v in zip(self.params, params, strict=False)}
        else:
            assert isinstance(params, dict)
            given = dict(params)
            unknown = [k for k in given if k not in by_name]
            if unknown and not self.var_kw:
                raise self._error(f"unknown parameter {unknown[0]!r}; expected {self.expected()}")
        for p in self.params:
            if p.name not in given:
                if p.required:
                    raise self._error(f"missing parameter {p.describe()}")
                continue
            given[p.name] = self._check(p, given[p.name])
        return given

    def _check(self, p: _Param, value: object) -> object:
        allowed = _plain_types(p.hint) if p.hint is not None else None
        if allowed is None:
            return value
        ok = any(
            isinstance(value, _KINDS[t][1]) and not (isinstance(value, bool) and t is not bool)
            if t in _KINDS
            else isinstance(value, t)
            for t in allowed
        )
        if not ok:
            want = " or ".join("null" if t is type(None) else _KINDS[t][0] for t in allowed)
            raise self._error(
                f"parameter {p.name!r} must be {want} ({_hint_name(p.hint)}), got {_seen(value)}"
            )
        if float in allowed and int not in allowed and type(value) is int:
            return float(value)
        return value

    def _error(self, text: str) -> RpcError:
        return RpcError(INVALID_PARAMS, f"{self.name}: {text}")


# --- JSON ----------------------------------------------------------------------------------------


def _refuse_constant(name: str) -> object:
    raise ValueError(f"{name} is not JSON")


def _clean(obj: Any) -> Any:
    """Something json.dumps can write: non-finite floats → null, dataclasses, numpy scalars/arrays."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _clean(dataclasses.asdict(obj))
    if hasattr(obj, "tolist"):  # numpy scalars and arrays
        return _clean(obj.tolist())
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _dumps(obj: object) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode() + b"\n"


def _error_reply(req_id: object, err: RpcError) -> dict[str, object]:
    return {"jsonrpc": "2.0", "id": req_id, "error": err.to_json()}


def _valid_id(req: Mapping[str, object]) -> object:
    rid = req.get("id")
    return rid if isinstance(rid, (str, int, float)) and not isinstance(rid, bool) else None


# --- server --------------------------------------------------------------------------------------


async def _topic_method(topic: str) -> None:
    """Signature of the built-in subscribe/unsubscribe (the server implements them itself)."""


class _Client:
    """One connection: its subscriptions and its bounded queue of notifications."""

    def __init__(self, writer: asyncio.StreamWriter, queue_size: int) -> None:
        self.writer = writer
        self.topics: set[str] = set()
        self.queue: asyncio.Queue[bytes] = asyncio.Queue(maxsize=queue_size)
        self.sender = asyncio.create_task(self._send_loop())

    async def write(self, data: bytes) -> None:
        self.writer.write(data)
        await self.writer.drain()

    async def _send_loop(self) -> None:
        with contextlib.suppress(ConnectionError):
            while True:
                await self.write(await self.queue.get())

    def close(self) -> None:
        self.sender.cancel()
        self.writer.close()


class RpcServer:
    """JSON-RPC 2.0 server on a Unix socket; see the module docstring for the protocol."""

    def __init__(
        self,
        path: Path,
        methods: Mapping[str, Method],
        *,
        max_message: int = 65536,
        mode: int = 0o660,
        queue_size: int = 256,
        topics: Collection[str] | None = None,
    ) -> None:
        clash = [name for name in _BUILTINS if name in methods]
        if clash:
            raise ValueError(f"method {clash[0]!r} is built into RpcServer; rename it")
        self.path = Path(path)
        self.max_message = max_message
        self.mode = mode
        self.queue_size = queue_size
        self.topics = frozenset(topics) if topics is not None else None
        self._methods = dict(methods)
        self._sigs = {name: _Signature(name, fn) for name, fn in methods.items()}
        self._builtin_sigs = {name: _Signature(name, _topic_method) for name in _BUILTINS}
        self._server: asyncio.AbstractServer | None = None
        self._clients: set[_Client] = set()
        self._inode: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._counts = {"requests": 0, "errors": 0, "dropped_notifications": 0}

    @property
    def stats(self) -> dict[str, int]:
        return {**self._counts, "clients": len(self._clients)}

    # lifecycle

    async def start(self) -> None:
        """Listen on the socket: replaces a stale socket file, refuses if another daemon answers."""
        if len(os.fsencode(self.path)) > SOCKET_PATH_MAX:
            raise SocketPathError(
                f"socket path {self.path} is {len(os.fsencode(self.path))} bytes; Unix sockets allow "
                f"at most {SOCKET_PATH_MAX}: choose a shorter path"
            )
        if not self.path.parent.is_dir():
            raise SocketPathError(
                f"directory {self.path.parent} of the socket does not exist: create it "
                "(systemd's RuntimeDirectory=tvsd does) or choose another path"
            )
        self._loop = asyncio.get_running_loop()
        await self._remove_stale()
        try:
            self._server = await asyncio.start_unix_server(
                self._serve, path=str(self.path), limit=self.max_message
            )
        except PermissionError as exc:
            raise SocketPathError(
                f"cannot create socket {self.path}: {exc.strerror}; "
                "run as the tvsd user or choose another path"
            ) from exc
        os.chmod(self.path, self.mode)
        self._inode = self.path.stat().st_ino
        log.info("JSON-RPC listening on %s (mode %o)", self.path, self.mode)

    async def _remove_stale(self) -> None:
        try:
            st = self.path.lstat()
        except FileNotFoundError:
            return
        if not stat.S_ISSOCK(st.st_mode):
            raise SocketPathError(f"{self.path} exists and is not a socket: remove it or choose another path")
        try:
            _, writer = await asyncio.wait_for(asyncio.open_unix_connection(str(self.path)), 1.0)
        except (ConnectionRefusedError, FileNotFoundError, TimeoutError):
            log.info("removing stale socket %s", self.path)
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()
            return
        writer.close()
        raise DaemonAlreadyRunning(
            f"another tvsd answers on {self.path}: stop it first (`tvsctl shutdown` or `systemctl stop tvsd`)"
        )

    async def close(self) -> None:
        """Stop listening, close every client and remove the socket file (if it is still ours)."""
        if self._server is not None:
            self._server.close()
        for client in list(self._clients):
            client.close()
        if self._server is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._server.wait_closed(), 2.0)
            self._server = None
        with contextlib.suppress(FileNotFoundError):
            if self._inode is not None and self.path.stat().st_ino == self._inode:
                self.path.unlink()
        self._inode = None

    async def __aenter__(self) -> RpcServer:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # notifications

    def publish(self, topic: str, params: object) -> None:
        """Queue a notification for every subscriber of `topic`; drops (and counts) when a queue is full."""
        line: bytes | None = None
        for client in self._clients:
            if topic not in client.topics:
                continue
            if line is None:
                line = _dumps({"jsonrpc": "2.0", "method": topic, "params": _clean(params)})
            try:
                client.queue.put_nowait(line)
            except asyncio.QueueFull:
                self._counts["dropped_notifications"] += 1

    def publish_threadsafe(self, topic: str, params: object) -> None:
        """`publish` from another thread (the control thread): hands it to the event loop."""
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self.publish, topic, params)

    # connections

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        client = _Client(writer, self.queue_size)
        self._clients.add(client)
        try:
            while True:
                try:
                    line = await reader.readline()
                except ValueError:  # asyncio's limit overrun: the line is longer than max_message
                    self._counts["errors"] += 1
                    err = RpcError(
                        INVALID_REQUEST,
                        f"message longer than {self.max_message} bytes; closing this connection "
                        "(send one JSON object per line)",
                    )
                    await client.write(_dumps(_error_reply(None, err)))
                    break
                if not line:
                    break
                reply = await self._handle_line(line, client)
                if reply is not None:
                    await client.write(reply)
        except ConnectionError:
            pass
        finally:
            self._clients.discard(client)
            client.close()

    async def _handle_line(self, line: bytes, client: _Client) -> bytes | None:
        if not line.strip():
            return None
        try:
            msg = json.loads(line, parse_constant=_refuse_constant)
        except (ValueError, RecursionError) as exc:
            self._counts["errors"] += 1
            text = f"not JSON ({exc}); send one JSON-RPC 2.0 object per line"
            return _dumps(_error_reply(None, RpcError(PARSE_ERROR, text)))
        if isinstance(msg, list):
            if not msg:
                self._counts["errors"] += 1
                return _dumps(
                    _error_reply(None, RpcError(INVALID_REQUEST, "empty batch: send [] of requests"))
                )
            replies = await asyncio.gather(*(self._handle(m, client) for m in msg))
            done = [r for r in replies if r is not None]
            return self._encode(done) if done else None
        reply = await self._handle(msg, client)
        return None if reply is None else self._encode(reply)

    def _encode(self, reply: object) -> bytes:
        try:
            return _dumps(reply)
        except (TypeError, ValueError) as exc:  # unreachable for replies built from _clean'd results
            self._counts["errors"] += 1
            return _dumps(_error_reply(None, RpcError(INTERNAL_ERROR, f"reply is not JSON: {exc}")))

    async def _handle(self, msg: object, client: _Client) -> dict[str, object] | None:
        self._counts["requests"] += 1
        try:
            method, params, req_id, notify = self._parse_request(msg)
            result = _clean(await self._call(method, params, client))
        except RpcError as err:
            self._counts["errors"] += 1
            if isinstance(msg, dict) and "id" not in msg and err.code != INVALID_REQUEST:
                return None
            return _error_reply(_valid_id(msg) if isinstance(msg, dict) else None, err)
        except Exception as exc:
            self._counts["errors"] += 1
            name = msg.get("method") if isinstance(msg, dict) else None
            log.exception("JSON-RPC method %r failed", name)
            if isinstance(msg, dict) and "id" not in msg:
                return None
            bug = RpcError(INTERNAL_ERROR, f"{name}: internal error ({type(exc).__name__}: {exc})")
            return _error_reply(_valid_id(msg) if isinstance(msg, dict) else None, bug)
        return None if notify else {"jsonrpc": "2.0", "id": req_id, "result": result}

    def _parse_request(self, msg: object) -> tuple[str, object, object, bool]:
        def bad(text: str) -> RpcError:
            return RpcError(INVALID_REQUEST, f"not a JSON-RPC 2.0 request: {text}")

        if not isinstance(msg, dict):
            raise bad(f"expected an object, got {_seen(msg)}")
        if msg.get("jsonrpc") != "2.0":
            raise bad(f'"jsonrpc" must be "2.0", got {_seen(msg.get("jsonrpc"))}')
        method = msg.get("method")
        if not isinstance(method, str):
            raise bad(f'"method" must be a string, got {_seen(method)}')
        params = msg.get("params")
        if "params" in msg and not isinstance(params, (list, dict)):
            raise bad(f'"params" must be an array or an object, got {_seen(params)}')
        if "id" in msg and msg["id"] is not None and _valid_id(msg) is None:
            raise bad(f'"id" must be a string, a number or null, got {_seen(msg["id"])}')
        return method, params, msg.get("id"), "id" not in msg

    async def _call(self, method: str, params: object, client: _Client) -> object:
        if method in _BUILTINS:
            topic = self._builtin_sigs[method].bind(params)["topic"]
            return self._subscribe(client, topic, on=method == "subscribe")
        fn = self._methods.get(method)
        if fn is None:
            offered = sorted([*self._methods, *_BUILTINS])
            raise RpcError(
                METHOD_NOT_FOUND, f"unknown method {method!r}; tvsd offers: {', '.join(offered)}", offered
            )
        return await fn(**self._sigs[method].bind(params))

    def _subscribe(self, client: _Client, topic: str, on: bool = True) -> dict[str, object]:
        if self.topics is not None and topic not in self.topics:
            raise RpcError(
                INVALID_PARAMS,
                f"unknown topic {topic!r}; topics: {', '.join(sorted(self.topics))}",
                sorted(self.topics),
            )
        (client.topics.add if on else client.topics.discard)(topic)
        return {"topic": topic, "subscribed": on}


class ThreadedRpcServer:
    """An `RpcServer` on its own event loop in a thread: for tests, benchmarks and tools.

    ``with ThreadedRpcServer(path, methods) as t: ...`` — ``t.loop`` and ``t.server`` are there to
    schedule work (``asyncio.run_coroutine_threadsafe(coro, t.loop)``).
    """

    def __init__(self, path: Path, methods: Mapping[str, Method], **kwargs: Any) -> None:
        self.path = Path(path)
        self.server = RpcServer(self.path, methods, **kwargs)
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, name="rpc-server", daemon=True)

    def __enter__(self) -> ThreadedRpcServer:
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self.server.start(), self.loop).result(10.0)
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            asyncio.run_coroutine_threadsafe(self.server.close(), self.loop).result(10.0)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(10.0)
            self.loop.close()


# --- benchmark -----------------------------------------------------------------------------------


def bench_rpc(n: int = 2000) -> dict[str, float]:
    """Round-trip latency of a ``status`` call through the real socket and `RpcClient`, in µs.

    The server runs on an event loop in a thread (as in the daemon); the blocking client calls from
    this thread. ``python -c "from tvsd.daemon.rpc import bench_rpc; print(bench_rpc())"``
    """
    from tvsd.cli.client import RpcClient

    async def status() -> dict[str, object]:
        return {
            "state": "scanning",
            "rps": 25.0,
            "phi_deg": 12.5,
            "gamma_deg": -3.25,
            "faults": [],
            "gains": {"Gp": 1.0, "Gd": 0.1, "Gr": 0.5, "G0": 0.0},
            "recording": False,
            "uptime_s": 123.4,
        }

    with (
        tempfile.TemporaryDirectory(prefix="tvsd-bench-") as tmp,
        ThreadedRpcServer(Path(tmp) / "bench.sock", {"status": status}) as threaded,
        RpcClient(threaded.path) as client,
    ):
        for _ in range(min(100, n)):  # warm-up
            client.call("status")
        samples = []
        for _ in range(n):
            t0 = time.perf_counter()
            client.call("status")
            samples.append(time.perf_counter() - t0)
    samples.sort()

    def pct(q: float) -> float:
        return samples[min(len(samples) - 1, int(q * len(samples)))] * 1e6

    return {
        "n": float(n),
        "p50_us": pct(0.50),
        "p99_us": pct(0.99),
        "max_us": samples[-1] * 1e6,
        "mean_us": sum(samples) / len(samples) * 1e6,
    }
