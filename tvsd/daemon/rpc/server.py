"""The JSON-RPC server's transport: the Unix socket file (stale ones replaced, a running daemon
refused), the connections (at most ``Limits.max_clients``; each read only as fast as its token
bucket allows) and their framing (one line at most ``max_message`` bytes), and the notifications
to subscribers (a bounded queue per client; a full one drops and counts). What a line means is
`tvsd.daemon.rpc.dispatch`'s."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import stat
import threading
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from tvsd.config import SOCKET_PATH_MAX
from tvsd.daemon.rpc.dispatch import Dispatcher
from tvsd.daemon.rpc.limits import Limits, TokenBucket, limit_error
from tvsd.errors import EXIT_FAILURE, EXIT_USAGE, TvsdError
from tvsd.rpc.protocol import INVALID_REQUEST, Method, RpcError, clean, dumps, error_reply

log = logging.getLogger("tvsd.daemon.rpc")


class SocketPathError(TvsdError, OSError):
    """The socket path cannot be used (too long, not a socket, directory missing or not writable)."""

    exit_status = EXIT_USAGE


class DaemonAlreadyRunning(TvsdError, FileExistsError):
    """Another daemon answers on the socket."""

    exit_status = EXIT_FAILURE


class _Client:
    """One connection: its subscriptions and its bounded queue of notifications."""

    def __init__(self, writer: asyncio.StreamWriter, queue_size: int, limits: Limits) -> None:
        self.writer = writer
        self.bucket = TokenBucket(limits.rate_per_s, limits.burst)
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
    """JSON-RPC 2.0 server on a Unix socket; see `tvsd.daemon.rpc` for the protocol."""

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
        self.limits = limits if limits is not None else Limits()
        self._all_clients = TokenBucket(self.limits.rate_total_per_s, self.limits.burst)
        self.dispatch = Dispatcher(methods, self.limits, topics)
        self.path = Path(path)
        self.max_message = max_message
        self.mode = mode
        self.queue_size = queue_size
        self._server: asyncio.AbstractServer | None = None
        self._clients: set[_Client] = set()
        self._inode: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._counts = {"dropped_notifications": 0, "throttled": 0, "refused": 0}

    @property
    def topics(self) -> frozenset[str] | None:
        """The topics a client may subscribe to (None: any)."""
        return self.dispatch.topics

    @property
    def stats(self) -> dict[str, int]:
        return {**self.dispatch.counts, **self._counts, "clients": len(self._clients)}

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
            err = limit_error(
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
                    err = RpcError(
                        INVALID_REQUEST,
                        f"message longer than {self.max_message} bytes; closing this connection "
                        "(send one JSON object per line)",
                    )
                    await client.write(self.dispatch.error(err))
                    break
                if not line:
                    break
                await self._throttle(client, line)
                reply = await self.dispatch.handle_line(line, client.topics)
                if reply is not None:
                    await client.write(reply)
        except ConnectionError:
            pass
        finally:
            self._clients.discard(client)
            client.close()

    async def _throttle(self, client: _Client, line: bytes) -> None:
        """Pause this connection (only) while it is over its request rate, or while all of them
        together are over theirs (each waits its turn: the shared bucket's debt orders them); a
        batch counts each member (estimated from the line, capped at max_batch, before parsing
        it). Paused, a connection is not read: the API's load on the event loop is bounded
        whatever the number of clients."""
        n = 1
        if line.lstrip()[:1] == b"[":
            n = max(1, min(self.limits.max_batch, line.count(b'"method"')))
        pause = max(client.bucket.wait(n), self._all_clients.wait(n))
        if pause > 0:
            self._counts["throttled"] += 1
            await asyncio.sleep(pause)


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
