"""The JSON-RPC 2.0 server: a Unix socket, newline-delimited JSON, one object (or batch array) per line.

This module owns the transport: the socket file (stale ones replaced, a running daemon refused),
the connections and their framing, and the subscriptions. What one message must look like — the
request checks, method lookup, params binding and the error codes — is `tvsd.rpc.protocol`
(its names are re-exported here). The daemon hands `RpcServer` a table of ``async def`` methods.

Built-in methods: ``subscribe(topic)`` and ``unsubscribe(topic)``. `RpcServer.publish` pushes
``{"jsonrpc": "2.0", "method": topic, "params": ...}`` to every client subscribed to ``topic``. It
never blocks: each client has a bounded queue drained by its own task, and a notification that
finds the queue full is dropped and counted (``stats["dropped_notifications"]``) — a slow
``tvsctl points`` must not slow the scanner. Call ``publish`` from the event-loop thread; from the
control thread use ``server.publish_threadsafe(topic, params)``.

Requests of one connection are handled in order; a batch's requests run concurrently, at most
``Limits.max_concurrent`` at a time, the event loop served between groups.

Bounds (`Limits`, from the config's ``daemon:`` section; README "Daemon API limits"): a client
sending faster than ``rate_per_s`` requests (a batch counts each member) is slowed down — its next
line is read only when its token bucket allows — so no client can hog the event loop; a batch
longer than ``max_batch``, a reply longer than ``max_reply_bytes`` and a connection beyond
``max_clients`` get a -32003 LIMIT_ERROR naming the limit (``error.data``: limit, value, seen).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import stat
import tempfile
import threading
import time
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tvsd.errors import EXIT_FAILURE, EXIT_USAGE, TvsdError
from tvsd.rpc.protocol import (
    DEVICE_ERROR,
    INTERNAL_ERROR,
    INVALID_PARAMS,
    INVALID_REQUEST,
    LIMIT_ERROR,
    METHOD_NOT_FOUND,
    PARSE_ERROR,
    STATE_ERROR,
    Method,
    MethodTable,
    RpcError,
    clean,
    decode,
    dumps,
    error_reply,
    parse_request,
    reply_to_error,
    result_reply,
)

__all__ = [
    "DEVICE_ERROR",
    "INTERNAL_ERROR",
    "INVALID_PARAMS",
    "INVALID_REQUEST",
    "LIMIT_ERROR",
    "METHOD_NOT_FOUND",
    "PARSE_ERROR",
    "SOCKET_PATH_MAX",
    "STATE_ERROR",
    "DaemonAlreadyRunning",
    "Limits",
    "Method",
    "RpcError",
    "RpcServer",
    "SocketPathError",
    "ThreadedRpcServer",
    "bench_rpc",
]

log = logging.getLogger(__name__)

SOCKET_PATH_MAX = 107  # sun_path is 108 bytes on Linux, NUL included
_BUILTINS = ("subscribe", "unsubscribe")


class SocketPathError(TvsdError, OSError):
    """The socket path cannot be used (too long, not a socket, directory missing or not writable)."""

    exit_status = EXIT_USAGE


class DaemonAlreadyRunning(TvsdError, FileExistsError):
    """Another daemon answers on the socket."""

    exit_status = EXIT_FAILURE


@dataclass(frozen=True)
class Limits:
    """What one client may ask of the server (module docstring); defaults as the config's."""

    max_batch: int = 50  # requests in one batch line
    max_reply_bytes: int = 1 << 20  # one reply line (a status is ~2-5 KB)
    rate_per_s: float = 50.0  # requests per second per connection, sustained
    burst: int = 50  # requests a connection may send at once before the rate applies
    max_concurrent: int = 8  # a batch's requests in flight at once
    max_clients: int = 64  # connections at once

    def __post_init__(self) -> None:
        if self.burst < self.max_batch:
            raise ValueError(f"burst {self.burst} must be at least max_batch {self.max_batch}")


UNLIMITED = Limits(max_batch=1000, max_reply_bytes=1 << 30, rate_per_s=1e9, burst=10**9, max_clients=10**4)


def _limit_error(name: str, value: float, seen: float, text: str) -> RpcError:
    return RpcError(LIMIT_ERROR, text, {"limit": name, "value": value, "seen": seen})


class _Bucket:
    """A token bucket: `wait(n)` returns how long to pause before n more requests."""

    def __init__(self, rate: float, burst: int) -> None:
        self.rate, self.burst = rate, float(burst)
        self.tokens, self.t = float(burst), time.monotonic()

    def wait(self, n: int) -> float:
        now = time.monotonic()
        self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
        self.t = now
        self.tokens -= n
        return 0.0 if self.tokens >= 0 else -self.tokens / self.rate


# --- server --------------------------------------------------------------------------------------


async def _topic_method(topic: str) -> None:
    """Signature of the built-in subscribe/unsubscribe (the server implements them itself)."""


class _Client:
    """One connection: its subscriptions and its bounded queue of notifications."""

    def __init__(self, writer: asyncio.StreamWriter, queue_size: int, limits: Limits) -> None:
        self.writer = writer
        self.bucket = _Bucket(limits.rate_per_s, limits.burst)
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
        limits: Limits | None = None,
    ) -> None:
        clash = [name for name in _BUILTINS if name in methods]
        if clash:
            raise ValueError(f"method {clash[0]!r} is built into RpcServer; rename it")
        self.path = Path(path)
        self.max_message = max_message
        self.mode = mode
        self.queue_size = queue_size
        self.limits = limits if limits is not None else Limits()
        self.topics = frozenset(topics) if topics is not None else None
        self._methods = MethodTable(methods, also_offered=_BUILTINS)
        self._builtins = MethodTable(dict.fromkeys(_BUILTINS, _topic_method))
        self._server: asyncio.AbstractServer | None = None
        self._clients: set[_Client] = set()
        self._inode: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._counts = {"requests": 0, "errors": 0, "dropped_notifications": 0, "throttled": 0, "refused": 0}

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
                line = dumps({"jsonrpc": "2.0", "method": topic, "params": clean(params)})
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
        if len(self._clients) >= self.limits.max_clients:
            self._counts["refused"] += 1
            n = self.limits.max_clients
            err = _limit_error(
                "max_clients", n, len(self._clients) + 1,
                f"{n} clients are connected, the most tvsd serves (daemon.rpc_max_clients); "
                "closing this connection: retry later or raise the limit",
            )  # fmt: skip
            with contextlib.suppress(ConnectionError):
                writer.write(dumps(error_reply(None, err)))
                await writer.drain()
            writer.close()
            return
        client = _Client(writer, self.queue_size, self.limits)
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
                    await client.write(dumps(error_reply(None, err)))
                    break
                if not line:
                    break
                await self._throttle(client, line)
                reply = await self._handle_line(line, client)
                if reply is not None:
                    await client.write(reply)
        except ConnectionError:
            pass
        finally:
            self._clients.discard(client)
            client.close()

    async def _throttle(self, client: _Client, line: bytes) -> None:
        """Pause this connection (only) while it is over its request rate; a batch counts each
        member (estimated from the line, capped at max_batch, before parsing it)."""
        n = 1
        if line.lstrip()[:1] == b"[":
            n = max(1, min(self.limits.max_batch, line.count(b'"method"')))
        pause = client.bucket.wait(n)
        if pause > 0:
            self._counts["throttled"] += 1
            await asyncio.sleep(pause)

    async def _handle_line(self, line: bytes, client: _Client) -> bytes | None:
        if not line.strip():
            return None
        try:
            msg = decode(line)
        except RpcError as err:
            self._counts["errors"] += 1
            return dumps(error_reply(None, err))
        if isinstance(msg, list):
            if not msg:
                self._counts["errors"] += 1
                return dumps(error_reply(None, RpcError(INVALID_REQUEST, "empty batch: send [] of requests")))
            if len(msg) > self.limits.max_batch:
                self._counts["errors"] += 1
                n = self.limits.max_batch
                too_long = _limit_error(
                    "max_batch", n, len(msg),
                    f"batch of {len(msg)} requests; tvsd takes at most {n} in one line "
                    "(daemon.rpc_max_batch): split it",
                )  # fmt: skip
                return dumps(error_reply(None, too_long))
            replies: list[dict[str, object] | None] = []
            step = self.limits.max_concurrent
            for k in range(0, len(msg), step):
                if k:
                    await asyncio.sleep(0)  # the event loop's other work between groups
                replies += await asyncio.gather(*(self._handle(m, client) for m in msg[k : k + step]))
            done = [r for r in replies if r is not None]
            return self._encode(done) if done else None
        reply = await self._handle(msg, client)
        return None if reply is None else self._encode(reply)

    def _encode(self, reply: object) -> bytes:
        try:
            data = dumps(reply)
        except (TypeError, ValueError) as exc:  # unreachable for replies built from clean'd results
            self._counts["errors"] += 1
            return dumps(error_reply(None, RpcError(INTERNAL_ERROR, f"reply is not JSON: {exc}")))
        n = self.limits.max_reply_bytes
        if len(data) <= n:
            return data
        self._counts["errors"] += 1
        rid = reply.get("id") if isinstance(reply, dict) else None
        err = _limit_error(
            "max_reply_bytes", n, len(data),
            f"the reply would be {len(data)} bytes; tvsd sends at most {n} in one line "
            "(daemon.rpc_max_reply_bytes): ask for less in one request or batch",
        )  # fmt: skip
        return dumps(error_reply(rid, err))

    async def _handle(self, msg: object, client: _Client) -> dict[str, object] | None:
        self._counts["requests"] += 1
        try:
            req = parse_request(msg)
            result = clean(await self._call(req.method, req.params, client))
        except RpcError as err:
            self._counts["errors"] += 1
            return reply_to_error(msg, err)
        except Exception as exc:
            self._counts["errors"] += 1
            name = msg.get("method") if isinstance(msg, dict) else None
            log.exception("JSON-RPC method %r failed", name)
            bug = RpcError(INTERNAL_ERROR, f"{name}: internal error ({type(exc).__name__}: {exc})")
            return reply_to_error(msg, bug)
        return None if req.notify else result_reply(req.id, result)

    async def _call(self, method: str, params: object, client: _Client) -> object:
        if method in _BUILTINS:
            _, kwargs = self._builtins.bind(method, params)
            return self._subscribe(client, kwargs["topic"], on=method == "subscribe")
        fn, kwargs = self._methods.bind(method, params)
        return await fn(**kwargs)

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
    from tvsd.rpc.client import RpcClient

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
        ThreadedRpcServer(Path(tmp) / "bench.sock", {"status": status}, limits=UNLIMITED) as threaded,
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
