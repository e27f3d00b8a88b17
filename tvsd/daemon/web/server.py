"""The live view's HTTP server: aiohttp on the daemon's own event loop, read-only, push-limited.

Routes (GET only; anything else is 405): `/` the page, `/static/NAME` its scripts (package data,
read once at start), `/ws` the WebSocket of frames, `/api/snapshot` everything the page starts
from as one JSON object, `/api/stats` the server's own counters, `/report?path=P` a doctor
report rendered, `/reports/P` its files (tvsd.daemon.web.reports: no way out of the report
folders). Nothing a browser sends changes anything: messages on the WebSocket are ignored.

A browser can never slow the daemon. One task (`_tick`) samples the daemon's status at `push_hz`
(≤ 5 Hz) into the bounded LiveFeed and wakes each browser's sender; a sender builds its frame from
its cursor and awaits the socket itself. A sender still busy with its previous frame is skipped
(its next frame carries what it missed); one busy for longer than `stall_s` is dropped. So per
browser there is at most one frame in flight: its kernel send buffer (`send_buffer_kib`), the
transport's high-water mark (HIGH_WATER, 64 KiB) and one frame — no queue. The IMU window and the point ring
take the daemon's data by copy on the loop's thread, O(batch).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import socket
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aiohttp import WSMsgType, web

from tvsd.config import WebSettings
from tvsd.daemon.web.feed import Cursor, LiveFeed, encode
from tvsd.daemon.web.floor import FloorProbe
from tvsd.daemon.web.http import (
    WebUnavailable,
    no_icon,
    read_only,
    remove_stale,
    same_origin,
    security_headers,
    static_files,
)
from tvsd.daemon.web.reports import content_type, find_reports, resolve
from tvsd.daemon.web.spectra import ImuWindow
from tvsd.scan.points import Point

SPECTRA_PERIOD_S = 1.0
HIGH_WATER = 65536  # bytes a browser's transport holds before its sender waits
REPORTS_PERIOD_S = 10.0


@dataclass(eq=False)
class _Browser:
    ws: web.WebSocketResponse
    request: web.Request
    cursor: Cursor = field(default_factory=Cursor)
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    busy_since: float | None = None  # loop time the frame in flight was handed to the socket
    frames: int = 0
    skipped: int = 0
    sender: asyncio.Task[None] | None = None

    def buffered(self) -> int:
        transport = self.request.transport
        return transport.get_write_buffer_size() if transport is not None else 0


class WebView:
    """The live view of one daemon. `status` returns the daemon's status as JSON (what the RPC
    `status` method returns); `point` and `imu_batch` are the daemon's taps (event-loop thread)."""

    def __init__(
        self,
        settings: WebSettings,
        status: Callable[[], dict[str, Any]],
        data_dir: Path,
        *,
        imu_rate_hz: float,
        control_period_s: float,
        log: Callable[[str], None] | None = None,
    ) -> None:
        self.settings = settings
        self._status = status
        self.data_dir = data_dir
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self.feed = LiveFeed(settings.history_s, settings.push_hz, settings.cloud_points)
        self.imu = ImuWindow(imu_rate_hz, settings.spectrum_s)
        self.floor = FloorProbe(control_period_s, settings.floor_s, settings.floor_every_s)
        self.static = static_files()
        self.url: str | None = None
        self._browsers: set[_Browser] = set()
        self._runner: web.AppRunner | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._reports_task: asyncio.Task[None] | None = None
        self._spectra_task: asyncio.Task[None] | None = None
        self._socket_inode: int | None = None
        self.counts = {
            "ticks": 0,
            "frames": 0,
            "skipped": 0,
            "dropped": 0,
            "refused": 0,
            "max_buffered_bytes": 0,
            "max_frame_bytes": 0,
        }
        # What the server costs the event loop's thread, in its CPU time (a loaded machine's waits
        # are not counted): per tick and per frame built, newest 500 each; and how late the tick woke.
        self._work: list[float] = []
        self._frame_work: list[float] = []
        self._late: list[float] = []

    # --- the daemon's taps (event-loop thread) ------------------------------------------------------
    def point(self, p: Point) -> None:
        self.feed.point(p)

    def imu_batch(self, batch: Any) -> None:
        self.imu.push(batch.sensor, batch.gyro, batch.accel)

    # --- lifecycle ------------------------------------------------------------------------------------
    async def start(self) -> None:
        app = web.Application(middlewares=[security_headers])
        app.router.add_get("/", self._index)
        app.router.add_get("/report", self._report_page)
        app.router.add_get("/static/{name}", self._static)
        app.router.add_get("/ws", self._ws)
        app.router.add_get("/api/snapshot", self._snapshot)
        app.router.add_get("/api/stats", self._stats)
        app.router.add_get("/reports/{path:.+}", self._report_file)
        app.router.add_get("/favicon.ico", no_icon)
        app.router.add_route("*", "/{tail:.*}", read_only)
        runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await runner.setup()
        s = self.settings
        try:
            if s.socket is not None:
                await remove_stale(s.socket)
                site: web.BaseSite = web.UnixSite(runner, str(s.socket))
                await site.start()
                os.chmod(s.socket, 0o660)
                self._socket_inode = s.socket.stat().st_ino
                self.url = f"unix:{s.socket}"
            else:
                site = web.TCPSite(runner, s.host, s.port, reuse_address=True)
                await site.start()
                host, port = runner.addresses[0][:2]
                self.url = f"http://{host if ':' not in host else f'[{host}]'}:{port}/"
        except OSError as exc:
            await runner.cleanup()
            where = s.socket if s.socket is not None else f"{s.host}:{s.port}"
            raise WebUnavailable(
                f"cannot listen on {where}: {exc.strerror or exc}; choose another web.port / "
                "web.socket in the config, or stop what holds it"
            ) from None
        self._runner = runner
        self.floor.start()
        self._tasks = [asyncio.create_task(self._tick(), name="web-tick")]
        self._reports_task = asyncio.create_task(self._scan_reports())  # listed in the first hello
        self.log(f"tvsd: live view on {self.url}")

    async def close(self) -> None:
        for b in list(self._browsers):
            self._drop(b, count=False)
        for task in [*self._tasks, self._reports_task, self._spectra_task]:
            if task is not None:
                task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._tasks = []
        await self.floor.close()
        if self._runner is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._runner.cleanup(), 2.0)
            self._runner = None
        sock = self.settings.socket
        if sock is not None and self._socket_inode is not None:
            with contextlib.suppress(OSError):
                if sock.stat().st_ino == self._socket_inode:
                    sock.unlink()

    # --- the push ---------------------------------------------------------------------------------------
    async def _tick(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.settings.push_hz
        deadline = loop.time()
        spectra_due = reports_due = 0.0
        while True:
            deadline += period
            await asyncio.sleep(max(0.0, deadline - loop.time()))
            now = loop.time()
            if now - deadline > period:  # a stalled loop: no burst of catch-up ticks
                deadline = now
            t0 = time.thread_time()
            self._keep(self._late, max(0.0, now - deadline))
            self.feed.sample(self._status())
            self.feed.set_floor(self.floor.result, self.floor.seq)
            if self._browsers and now >= spectra_due and self._spectra_task is None:
                spectra_due = now + SPECTRA_PERIOD_S
                self._spectra_task = asyncio.create_task(self._spectra(self.feed.status.get("rps") or 0.0))
            if self._browsers and now >= reports_due and self._reports_task is None:
                reports_due = now + REPORTS_PERIOD_S
                self._reports_task = asyncio.create_task(self._scan_reports())
            for b in list(self._browsers):
                buffered = b.buffered()
                self.counts["max_buffered_bytes"] = max(self.counts["max_buffered_bytes"], buffered)
                if b.busy_since is None:
                    b.wake.set()
                elif now - b.busy_since > self.settings.stall_s:
                    self._drop(b)
                else:
                    b.skipped += 1
                    self.counts["skipped"] += 1
            self.counts["ticks"] += 1
            self._keep(self._work, time.thread_time() - t0)

    @staticmethod
    def _keep(series: list[float], value: float) -> None:
        series.append(value)
        if len(series) > 500:
            del series[:250]

    async def _spectra(self, rps: float) -> None:
        """The Welch spectra in a worker thread (FFTs release the GIL: 3–5 ms of work, not on the
        loop); the samples are copied here first, on the loop's thread that writes them."""
        try:
            samples = self.imu.snapshot()
            spectra = await asyncio.to_thread(self.imu.spectra_of, samples, rps)
            if spectra is not None:
                self.feed.set_spectra(await asyncio.to_thread(json.dumps, spectra, separators=(",", ":")))
        finally:
            self._spectra_task = None

    async def _scan_reports(self) -> None:
        try:
            self.feed.set_reports(await asyncio.to_thread(find_reports, self.data_dir))
        finally:
            self._reports_task = None

    async def _send(self, b: _Browser) -> None:
        loop = asyncio.get_running_loop()
        hello = True
        with contextlib.suppress(ConnectionError, RuntimeError):
            while True:
                if not hello:
                    await b.wake.wait()
                b.wake.clear()
                t0 = time.thread_time()
                data = encode(self.feed.frame(b.cursor, hello=hello))
                if not hello:
                    self._keep(self._frame_work, time.thread_time() - t0)
                hello = False
                self.counts["max_frame_bytes"] = max(self.counts["max_frame_bytes"], len(data))
                b.busy_since = loop.time()
                await b.ws.send_str(data)
                b.busy_since = None
                b.frames += 1
                self.counts["frames"] += 1

    def _drop(self, b: _Browser, *, count: bool = True) -> None:
        """A browser that stopped reading: its socket is aborted (what it holds is freed)."""
        if count:
            self.counts["dropped"] += 1
        self._browsers.discard(b)
        if b.sender is not None:
            b.sender.cancel()
        transport = b.request.transport
        if transport is not None:
            transport.abort()

    # --- handlers ---------------------------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.Response:
        return self._static_response("index.html")

    async def _report_page(self, request: web.Request) -> web.Response:
        return self._static_response("report.html")

    async def _static(self, request: web.Request) -> web.Response:
        return self._static_response(request.match_info["name"])

    def _static_response(self, name: str) -> web.Response:
        if name not in self.static:
            raise web.HTTPNotFound(text=f"no {name} here")
        body, ctype = self.static[name]
        return web.Response(body=body, content_type=ctype, charset="utf-8")

    async def _ws(self, request: web.Request) -> web.StreamResponse:
        if not same_origin(request):
            raise web.HTTPForbidden(text="the live view answers pages of its own origin only")
        if len(self._browsers) >= self.settings.max_clients:
            self.counts["refused"] += 1
            raise web.HTTPServiceUnavailable(
                text=f"{self.settings.max_clients} browsers are watching already (web.max_clients)"
            )
        # writer_limit 1: the sender waits for the transport after every frame it finds above its
        # high-water mark (aiohttp's default waits only every 256 KiB written)
        ws = web.WebSocketResponse(max_msg_size=4096, heartbeat=None, writer_limit=1)
        await ws.prepare(request)
        transport = request.transport
        if transport is not None:
            transport.set_write_buffer_limits(high=HIGH_WATER)
            sock = transport.get_extra_info("socket")
            if sock is not None:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self.settings.send_buffer_kib * 1024)
        b = _Browser(ws, request)
        self._browsers.add(b)
        b.sender = asyncio.create_task(self._send(b), name="web-send")
        try:
            async for msg in ws:  # read-only: what a browser says is ignored
                if msg.type == WSMsgType.ERROR:
                    break
        finally:
            self._browsers.discard(b)
            b.sender.cancel()
        return ws

    async def _snapshot(self, request: web.Request) -> web.Response:
        return web.Response(
            text=encode(self.feed.frame(Cursor(), hello=True)), content_type="application/json"
        )

    async def _stats(self, request: web.Request) -> web.Response:
        return web.json_response(self.stats())

    def stats(self) -> dict[str, Any]:
        """The server's counters, and what it costs the event loop (per tick, µs)."""
        work = sorted(self._work) or [math.nan]
        frame = sorted(self._frame_work) or [math.nan]
        late = sorted(self._late) or [math.nan]

        def p(xs: list[float], q: float) -> float | None:
            v = xs[min(len(xs) - 1, int(q * len(xs)))] * 1e6
            return None if math.isnan(v) else round(v, 1)

        return {
            **self.counts,
            "browsers": [
                {"frames": b.frames, "skipped": b.skipped, "buffered_bytes": b.buffered()}
                for b in self._browsers
            ],
            "tick_cpu_p50_us": p(work, 0.5),
            "tick_cpu_max_us": p(work, 1.0),
            "frame_cpu_p50_us": p(frame, 0.5),
            "frame_cpu_max_us": p(frame, 1.0),
            "tick_late_p99_us": p(late, 0.99),
            "tick_late_max_us": p(late, 1.0),
            "url": self.url,
            "push_hz": self.settings.push_hz,
        }

    async def _report_file(self, request: web.Request) -> web.StreamResponse:
        rel = request.match_info["path"]
        path = await asyncio.to_thread(resolve, self.data_dir, rel)
        if path is None:
            raise web.HTTPNotFound(text=f"no report file {rel!r} in the data directory")
        return web.FileResponse(path, headers={"Content-Type": content_type(path)})
