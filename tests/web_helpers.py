"""A browser that never reads, for the live view's tests (tests/test_web_server.py against a
`WebView`, tests/test_web_view.py against a running daemon): `from web_helpers import silent_browser`."""

from __future__ import annotations

import asyncio
import socket


async def silent_browser(url: str) -> socket.socket:
    """Open the live view's WebSocket at `url` (http://host:port/) with a 4 KiB receive buffer and
    never read it: what the server sends fills both sides' buffers at once. Close it when done."""
    host, port = url.removeprefix("http://").rstrip("/").split(":")
    raw = socket.socket()
    raw.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    raw.setblocking(False)
    await asyncio.get_running_loop().sock_connect(raw, (host, int(port)))
    raw.send(
        b"GET /ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )
    return raw
