"""The API's bounds (issue 13 item 3) over a real Unix socket, with a small fake method table.

Each test below failed before the bounds existed: a 400-digit integer to a float parameter was a
-32603 internal error (float overflow), ``"id": 1e999`` got "reply is not JSON", a batch of any
length ran at once (300 `status` calls stalled the daemon's loop 1.8 s; 500 made an 11.8 MB
reply), and a client could send as fast as the socket takes.
"""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
from conftest import until
from rpc_helpers import Conn, run

from tvsd.daemon.rpc import INVALID_PARAMS, INVALID_REQUEST, LIMIT_ERROR, Limits, RpcServer


async def speed(rps: float) -> dict[str, float]:
    return {"rps": rps}


async def count(n: int) -> dict[str, int]:
    return {"n": n}


async def big(kb: int) -> str:
    return "x" * (kb * 1024)


IN_FLIGHT = {"now": 0, "max": 0}


async def slow() -> int:
    IN_FLIGHT["now"] += 1
    IN_FLIGHT["max"] = max(IN_FLIGHT["max"], IN_FLIGHT["now"])
    await asyncio.sleep(0.01)
    IN_FLIGHT["now"] -= 1
    return 1


METHODS: dict[str, Callable[..., Awaitable[object]]] = {
    "speed": speed,
    "count": count,
    "big": big,
    "slow": slow,
}


def _req(method: str, rid: int, **params: object) -> dict[str, object]:
    return {"jsonrpc": "2.0", "id": rid, "method": method, "params": params}


@pytest.mark.parametrize(
    ("raw", "words"),
    [
        (b'{"jsonrpc":"2.0","id":1,"method":"speed","params":{"rps":' + b"9" * 400 + b"}}\n", "401 digits"),
        (b'{"jsonrpc":"2.0","id":1,"method":"speed","params":{"rps":1e999}}\n', "finite number"),
        (b'{"jsonrpc":"2.0","id":1,"method":"speed","params":{"rps":-1e301}}\n', "within ±1e+300"),
        (b'{"jsonrpc":"2.0","id":1,"method":"count","params":{"n":' + b"9" * 20 + b"}}\n", "within ±2**53"),
        (b'{"jsonrpc":"2.0","id":1,"method":"count","params":{"n":' + b"9" * 400 + b"}}\n", "2**53"),
    ],
)
def test_out_of_range_numbers_are_invalid_params_not_internal_errors(
    sock_path: Path, raw: bytes, words: str
) -> None:
    async def body() -> None:
        async with RpcServer(sock_path, METHODS):
            c = await Conn.open(sock_path)
            await c.send(raw)
            reply = await c.recv()
            assert reply["id"] == 1 and reply["error"]["code"] == INVALID_PARAMS, reply
            assert words in reply["error"]["message"] and "parameter" in reply["error"]["message"], reply
            assert (await c.call("speed", {"rps": 25}, rid=2))["result"] == {"rps": 25.0}

    run(body(), timeout=20.0)


@pytest.mark.parametrize("rid", [b"1e999", b"-1e999", b"9" * 30, b'"' + b"x" * 300 + b'"'])
def test_an_id_no_reply_could_carry_is_an_invalid_request(sock_path: Path, rid: bytes) -> None:
    async def body() -> None:
        async with RpcServer(sock_path, METHODS):
            c = await Conn.open(sock_path)
            await c.send(b'{"jsonrpc":"2.0","id":' + rid + b',"method":"speed","params":[1]}\n')
            reply = await c.recv()
            assert reply["id"] is None and reply["error"]["code"] == INVALID_REQUEST, reply
            assert '"id" must be' in reply["error"]["message"]

    run(body(), timeout=20.0)


def test_a_batch_longer_than_the_limit_is_refused_whole_and_fast(sock_path: Path) -> None:
    async def body() -> None:
        limits = Limits(max_batch=50, burst=1000)
        async with RpcServer(sock_path, METHODS, limits=limits):
            c = await Conn.open(sock_path)
            await c.send(json.dumps([_req("count", k, n=k) for k in range(300)]).encode() + b"\n")
            reply = await c.recv()
            assert isinstance(reply, dict) and reply["error"]["code"] == LIMIT_ERROR, str(reply)[:200]
            assert reply["error"]["data"] == {"limit": "max_batch", "value": 50, "seen": 300}
            assert "split it" in reply["error"]["message"]
            await c.send(json.dumps([_req("count", k, n=k) for k in range(50)]).encode() + b"\n")
            replies = await c.recv()
            assert [r["result"]["n"] for r in replies] == list(range(50))

    run(body(), timeout=20.0)


def test_a_reply_larger_than_the_limit_becomes_an_error_naming_it(sock_path: Path) -> None:
    async def body() -> None:
        async with RpcServer(sock_path, METHODS, limits=Limits(max_reply_bytes=64 * 1024)):
            c = await Conn.open(sock_path)
            assert len((await c.call("big", {"kb": 32}))["result"]) == 32 * 1024
            reply = await c.call("big", {"kb": 100}, rid=7)
            assert reply["id"] == 7 and reply["error"]["code"] == LIMIT_ERROR
            assert reply["error"]["data"]["limit"] == "max_reply_bytes"
            assert reply["error"]["data"]["seen"] > 100 * 1024
            batch = [_req("big", k, kb=20) for k in range(5)]  # 5 × 20 KB: the batch's reply is too large
            await c.send(json.dumps(batch).encode() + b"\n")
            reply = await c.recv()
            assert reply["id"] is None and reply["error"]["code"] == LIMIT_ERROR

    run(body(), timeout=20.0)


def test_a_batch_runs_at_most_max_concurrent_requests_at_once(sock_path: Path) -> None:
    async def body() -> None:
        IN_FLIGHT.update(now=0, max=0)
        async with RpcServer(sock_path, METHODS, limits=Limits(max_concurrent=4)):
            c = await Conn.open(sock_path)
            await c.send(json.dumps([_req("slow", k) for k in range(20)]).encode() + b"\n")
            assert len(await c.recv()) == 20
        assert IN_FLIGHT["max"] == 4

    run(body(), timeout=20.0)


def test_a_client_faster_than_its_rate_is_slowed_and_others_are_served(sock_path: Path) -> None:
    """150 pipelined requests at 50/s with a burst of 50: at least (150 − 50)/50 = 2 s to answer
    them all (a lower bound: a loaded machine only makes it later). Meanwhile a second client's
    call is answered (the slowing pauses that connection only)."""

    async def body() -> None:
        limits = Limits(rate_per_s=50.0, burst=50, max_batch=10)
        async with RpcServer(sock_path, METHODS, limits=limits) as server:
            flood, other = await Conn.open(sock_path), await Conn.open(sock_path)
            t0 = time.monotonic()
            await flood.send(b"".join(json.dumps(_req("count", k, n=k)).encode() + b"\n" for k in range(150)))
            assert (await other.call("count", {"n": 1}))["result"] == {"n": 1}
            got = [(await flood.recv())["result"]["n"] for _ in range(150)]
            elapsed = time.monotonic() - t0
            assert got == list(range(150))
            assert elapsed >= 0.95 * (150 - 50) / 50, elapsed
            assert server.stats["throttled"] > 0

    run(body(), timeout=20.0)


def test_all_clients_together_are_held_to_the_total_rate(sock_path: Path) -> None:
    """Four clients each within their own rate (1000/s) but together over the total (100/s, burst
    50): their 4 × 60 pipelined requests take at least (240 − 50)/100 = 1.9 s (a lower bound: a
    loaded machine only makes it later) and every one is answered, in order per client. Without
    the shared bucket they are answered as fast as the loop runs (well under 1 s here)."""

    async def body() -> None:
        limits = Limits(rate_per_s=1000.0, burst=50, max_batch=10, rate_total_per_s=100.0)
        async with RpcServer(sock_path, METHODS, limits=limits) as server:
            conns = [await Conn.open(sock_path) for _ in range(4)]
            t0 = time.monotonic()
            for c in conns:
                await c.send(b"".join(json.dumps(_req("count", k, n=k)).encode() + b"\n" for k in range(60)))
            for c in conns:
                assert [(await c.recv())["result"]["n"] for _ in range(60)] == list(range(60))
            elapsed = time.monotonic() - t0
            assert elapsed >= 0.95 * (240 - 50) / 100, elapsed
            assert server.stats["throttled"] > 0

    run(body(), timeout=30.0)


def test_connections_beyond_max_clients_are_told_and_closed(sock_path: Path) -> None:
    async def body() -> None:
        async with RpcServer(sock_path, METHODS, limits=Limits(max_clients=2)) as server:
            a, b = await Conn.open(sock_path), await Conn.open(sock_path)
            assert (await a.call("count", {"n": 1}))["result"] == {"n": 1}
            assert (await b.call("count", {"n": 2}))["result"] == {"n": 2}
            c = await Conn.open(sock_path)
            reply = await c.recv()
            assert reply["error"]["code"] == LIMIT_ERROR and reply["error"]["data"]["limit"] == "max_clients"
            assert await asyncio.wait_for(c.reader.read(), 5.0) == b""
            assert server.stats["refused"] == 1
            a.writer.close()
            await a.writer.wait_closed()
            await until(lambda: server.stats["clients"] < 2, 5.0, "the server to drop the closed client")
            d = await Conn.open(sock_path)
            assert (await d.call("count", {"n": 3}))["result"] == {"n": 3}

    run(body(), timeout=20.0)


@pytest.mark.parametrize(
    "raw",
    [
        b'{"jsonrpc":"2.0","id":1,"method":"' + b"m" * 50000 + b'"}\n',
        b'{"jsonrpc":"2.0","id":1,"method":"speed","params":{"' + b"k" * 50000 + b'":1}}\n',
    ],
)
def test_an_error_does_not_echo_a_whole_line(sock_path: Path, raw: bytes) -> None:
    """An unknown 50 KB method or parameter name came back whole: a 50 KB error "line"."""

    async def body() -> None:
        async with RpcServer(sock_path, METHODS):
            c = await Conn.open(sock_path)
            await c.send(raw)
            reply = await c.recv()
            message = reply["error"]["message"]
            assert len(message) <= 400 and message.endswith("characters, cut)"), message[-80:]

    run(body(), timeout=20.0)
