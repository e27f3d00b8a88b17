"""A raw-line client of the JSON-RPC server and a bounded `asyncio.run`, for the tests that drive
`tvsd.daemon.rpc` over its real socket (tests/test_rpc.py, tests/test_rpc_limits.py):
`from rpc_helpers import Conn, run`. The socket's path is conftest's `sock_path` fixture."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable
from pathlib import Path
from typing import Any


def run(coro: Awaitable[None], timeout: float = 10.0) -> None:
    """Run a test's coroutine, failing it (not hanging) after `timeout` seconds."""

    async def bounded() -> None:
        await asyncio.wait_for(coro, timeout)

    asyncio.run(bounded())


class Conn:
    """An asyncio client speaking raw lines."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer

    @classmethod
    async def open(cls, path: Path) -> Conn:
        # a 16 MiB line limit: the tests read replies up to the server's largest reply cap
        return cls(*await asyncio.open_unix_connection(str(path), limit=1 << 24))

    async def send(self, raw: bytes) -> None:
        self.writer.write(raw)
        await self.writer.drain()

    async def recv(self, timeout: float = 10.0) -> Any:
        line = await asyncio.wait_for(self.reader.readline(), timeout)
        assert line, "server closed the connection"
        return json.loads(line)

    async def call(self, method: str, params: Any = None, rid: Any = 1) -> Any:
        req: dict[str, Any] = {"jsonrpc": "2.0", "id": rid, "method": method}
        if params is not None:
            req["params"] = params
        await self.send(json.dumps(req).encode() + b"\n")
        return await self.recv()

    def close(self) -> None:
        self.writer.close()
