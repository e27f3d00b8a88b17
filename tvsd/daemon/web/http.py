"""The live view's HTTP edges: the page's files, the headers every answer carries, what a
read-only server answers to anything but GET, the origin check, and the Unix socket's stale file.
"""

from __future__ import annotations

import asyncio
import contextlib
import stat
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from aiohttp import web

from tvsd.errors import EXIT_UNAVAILABLE, TvsdError

STATIC_TYPES = {".html": "text/html", ".js": "text/javascript", ".css": "text/css"}
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; connect-src 'self'; "
    "frame-ancestors 'none'; form-action 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


class WebUnavailable(TvsdError, OSError):
    """The live view cannot listen where it was configured to."""

    exit_status = EXIT_UNAVAILABLE


def static_files() -> dict[str, tuple[bytes, str]]:
    """The page's files (package data), read once: name → (bytes, content type)."""
    folder = resources.files("tvsd.daemon.web") / "static"
    out = {}
    for item in folder.iterdir():
        suffix = Path(item.name).suffix
        if suffix in STATIC_TYPES:
            out[item.name] = (item.read_bytes(), STATIC_TYPES[suffix])
    return out


@web.middleware
async def security_headers(request: web.Request, handler: Callable[[web.Request], Any]) -> web.StreamResponse:
    try:
        response: web.StreamResponse = await handler(request)
    except web.HTTPException as exc:
        exc.headers.update(SECURITY_HEADERS)
        raise
    if not response.prepared:
        response.headers.update(SECURITY_HEADERS)
    return response


async def no_icon(request: web.Request) -> web.Response:
    return web.Response(status=204)


async def read_only(request: web.Request) -> web.Response:
    """Anything no route took: 404 for a GET, 405 for any method that would change something."""
    if request.method in ("GET", "HEAD"):
        raise web.HTTPNotFound(text=f"nothing at {request.path}: the live view is at /")
    raise web.HTTPMethodNotAllowed(request.method, ["GET", "HEAD"], text="the live view is read-only")


def same_origin(request: web.Request) -> bool:
    """A page of another origin may not read the stream (a browser sends Origin on WebSockets)."""
    origin = request.headers.get("Origin")
    if origin is None:
        return True  # not a browser page (a tool, a test)
    return urlsplit(origin).netloc == request.host


async def remove_stale(path: Path) -> None:
    """A socket file nobody answers on is removed; anything else there is refused."""
    try:
        st = path.lstat()
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise WebUnavailable(f"{path} exists and is not a socket: remove it or choose another web.socket")
    try:
        _, writer = await asyncio.wait_for(asyncio.open_unix_connection(str(path)), 1.0)
    except (ConnectionRefusedError, FileNotFoundError, TimeoutError):
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
        return
    writer.close()
    raise WebUnavailable(f"something answers on {path} already: stop it or choose another web.socket")
