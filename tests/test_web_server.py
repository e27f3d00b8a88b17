"""The live view's server in this process, on real sockets (TCP on loopback, a Unix socket), fed
by a stand-in for the daemon's status: routes, read-only, the push, slow and foreign browsers."""

from __future__ import annotations

import asyncio
import json
import os
import socket
import stat
import time
from pathlib import Path

import aiohttp
import pytest
from conftest import until
from web_helpers import silent_browser

from tvsd.config import WebSettings
from tvsd.daemon.web.feed import decode_points
from tvsd.daemon.web.server import HIGH_WATER, WebUnavailable, WebView
from tvsd.scan.points import Point


class FakeDaemon:
    """What the daemon hands the view: its status as JSON (the RPC `status` result's shape)."""

    def __init__(self) -> None:
        self.rps = 0.0
        self.faults: list[dict] = []

    def status(self) -> dict:
        self.rps += 0.5
        return {
            "state": "scanning",
            "rps": self.rps,
            "rps_setpoint": 25.0,
            "loop": {
                "rate_hz": 1e4,
                "missed_ticks": 0,
                "jitter_p99_us": 60.0,
                "jitter_max_us": 300.0,
                "ticks": 1,
            },
            "imu": {"state": "ok"},
            "link": {"state": "ok"},
            "points": {"total": 0, "no_imu": 0, "per_s": 0.0},
            "faults": list(self.faults),
        }


def _point(k: int) -> Point:
    values = dict.fromkeys(Point.__dataclass_fields__, 0.0)
    values.update(x=1.0 + k * 1e-4, y=0.5, z=0.1, sigma_x=3e-4, sigma_y=4e-4, flags=2)
    return Point(**values)


def _view(tmp_path: Path, **settings: object) -> tuple[WebView, FakeDaemon]:
    d = FakeDaemon()
    s = WebSettings(enabled=True, port=0, floor_every_s=0, **settings)  # type: ignore[arg-type]
    data = tmp_path / "data"
    (data / "doctor-a").mkdir(parents=True, exist_ok=True)
    (data / "doctor-a" / "report.md").write_text("# Model doctor: a\n\n**Verdict: `none`.**\n")
    (tmp_path / "secret.md").write_text("outside")
    return WebView(s, d.status, data, imu_rate_hz=1000.0, control_period_s=1e-4, log=lambda _: None), d


def test_pages_routes_and_nothing_but_reading(tmp_path: Path):
    async def main() -> None:
        view, _ = _view(tmp_path)
        await view.start()
        try:
            async with aiohttp.ClientSession(view.url) as http:
                async with http.get("/") as r:
                    assert r.status == 200 and "text/html" in r.headers["Content-Type"]
                    assert "default-src 'self'" in r.headers["Content-Security-Policy"]
                    assert "live.js" in await r.text()
                for name in ("live.js", "plot.js", "cloud.js", "report.js", "style.css"):
                    async with http.get(f"/static/{name}") as r:
                        assert r.status == 200, name
                await until(lambda: view.feed.samples.seq > 0, 10, "a first status sample")
                async with http.get("/api/snapshot") as r:
                    snap = await r.json()
                assert snap["status"]["state"] == "scanning" and snap["config"]["push_hz"] == 5.0
                async with http.get("/reports/doctor-a/report.md") as r:
                    assert r.status == 200 and r.headers["Content-Type"].startswith("text/markdown")
                    assert "Verdict" in await r.text()
                async with http.get("/report", params={"path": "doctor-a/report.md"}) as r:
                    assert r.status == 200
                for bad in (
                    "/reports/../secret.md",
                    "/reports/%2e%2e/secret.md",
                    "/reports/doctor-a/%2e%2e/%2e%2e/secret.md",
                    "/static/..%2f..%2fserver.py",
                    "/nothing",
                ):
                    async with http.get(bad) as r:
                        assert r.status == 404, bad
                        assert "outside" not in await r.text()
                for method in ("POST", "PUT", "DELETE", "PATCH"):
                    async with http.request(method, "/api/snapshot") as r:
                        assert r.status == 405, method
        finally:
            await view.close()

    asyncio.run(main())


def test_a_browser_gets_a_hello_then_frames_at_the_push_rate_and_new_points(tmp_path: Path):
    """push_hz 5: 2 s of frames holds about 10; at least 3 arrive however late this machine wakes
    (a frame that finds its browser busy is merged into the next, never queued)."""

    async def main() -> None:
        view, d = _view(tmp_path)
        await view.start()
        try:
            async with aiohttp.ClientSession(view.url) as http, http.ws_connect("/ws") as ws:
                hello = json.loads((await ws.receive(timeout=10)).data)
                assert hello["type"] == "hello" and hello["config"]["history_s"] == 60
                for k in range(7):
                    view.point(_point(k))
                d.faults.append(
                    {"t_unix": time.time(), "cause": "c", "action": "a", "kind": "control_overrun"}
                )
                frames, t0 = [], time.monotonic()
                while time.monotonic() - t0 < 2.0:
                    frames.append(json.loads((await ws.receive(timeout=10)).data))
                assert len(frames) >= 3
                xs = [x for f in frames if f["points"] for x in decode_points(f["points"])[:, 0]]
                assert xs == sorted(xs) and len(xs) == 7  # each point once, in order
                assert [f["faults"] for f in frames if "faults" in f][-1][0]["kind"] == "control_overrun"
                rps = [row[1] for f in frames for row in f["samples"]]
                assert rps == sorted(rps) and len(set(rps)) == len(rps)  # each sample once, in order
        finally:
            await view.close()

    asyncio.run(main())


def test_foreign_pages_and_browsers_past_the_limit_are_refused(tmp_path: Path):
    async def main() -> None:
        view, _ = _view(tmp_path, max_clients=1)
        await view.start()
        try:
            async with aiohttp.ClientSession(view.url) as http:
                with pytest.raises(aiohttp.WSServerHandshakeError) as err:
                    await http.ws_connect("/ws", headers={"Origin": "http://evil.example"})
                assert err.value.status == 403
                async with http.ws_connect("/ws") as first:
                    await first.receive(timeout=10)
                    with pytest.raises(aiohttp.WSServerHandshakeError) as err:
                        await http.ws_connect("/ws")
                    assert err.value.status == 503
                assert view.stats()["refused"] == 1
        finally:
            await view.close()

    asyncio.run(main())


@pytest.mark.slow
def test_a_browser_that_stops_reading_is_dropped_and_holds_a_bounded_buffer(tmp_path: Path):
    """A client that connects and never reads (4 KiB receive buffer, the server's send buffer at
    its 4 KiB floor): its 20 000-point hello (~0.8 MB) cannot go out, so its sender waits on the
    socket. It is dropped once it has held that frame for stall_s (3 s), while a reading browser's
    frames keep coming (no gap as long as stall_s: the push never waits for the slow one), and what
    the server buffered for it stays within the transport's high-water mark (64 KiB) and one frame."""

    async def main() -> None:
        view, _ = _view(tmp_path, stall_s=3.0, send_buffer_kib=4, cloud_points=20000)
        for k in range(20000):
            view.point(_point(k))
        await view.start()
        try:
            raw = await silent_browser(view.url)
            await until(lambda: view.stats()["browsers"], 10, "the silent client connected")
            async with aiohttp.ClientSession(view.url) as http, http.ws_connect("/ws", max_msg_size=0) as ws:
                await ws.receive(timeout=10)  # the reader's hello
                gaps, last, t0 = [], time.monotonic(), time.monotonic()
                while view.stats()["dropped"] == 0 and time.monotonic() - t0 < 20:
                    await ws.receive(timeout=10)
                    now = time.monotonic()
                    gaps.append(now - last)
                    last = now
                stats = view.stats()
            raw.close()
        finally:
            await view.close()
        assert stats["dropped"] == 1, stats
        assert gaps and max(gaps) < 3.0, gaps
        assert stats["max_buffered_bytes"] <= HIGH_WATER + stats["max_frame_bytes"], stats

    asyncio.run(main())


def test_a_unix_socket_for_a_reverse_proxy(tmp_path: Path):
    sock = tmp_path / "web.sock"
    sock.touch()  # a plain file there is refused, not replaced

    async def main() -> None:
        view, _ = _view(tmp_path, socket=sock)
        with pytest.raises(WebUnavailable, match="is not a socket"):
            await view.start()
        sock.unlink()
        stale = socket.socket(socket.AF_UNIX)  # a socket file left by a dead daemon is replaced
        stale.bind(str(sock))
        stale.close()
        await view.start()
        try:
            assert stat.S_IMODE(os.stat(sock).st_mode) == 0o660
            conn = aiohttp.UnixConnector(path=str(sock))
            async with aiohttp.ClientSession(connector=conn) as http, http.get("http://tvsd/") as r:
                assert r.status == 200
        finally:
            await view.close()
        assert not sock.exists()

    asyncio.run(main())


def test_a_port_in_use_is_one_clear_error(tmp_path: Path):
    holder = socket.socket()
    holder.bind(("127.0.0.1", 0))
    holder.listen()
    port = holder.getsockname()[1]

    async def main() -> None:
        view, _ = _view(tmp_path)
        view.settings = WebSettings(enabled=True, port=port)
        with pytest.raises(WebUnavailable, match=f"cannot listen on 127.0.0.1:{port}: .*web.port"):
            await view.start()

    try:
        asyncio.run(main())
    finally:
        holder.close()
