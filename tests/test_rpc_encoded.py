"""A result encoded once (tvsd.rpc.protocol.Encoded, the status's) answers exactly as the same
value returned as a dict: one request, a batch mixing both, non-finite floats, the reply bound."""

from __future__ import annotations

import asyncio
import json
import math
from dataclasses import replace

from tvsd.daemon.rpc.dispatch import Dispatcher
from tvsd.daemon.rpc.limits import UNLIMITED, Limits
from tvsd.rpc.protocol import Encoded

STATUS = {
    "state": "scanning",
    "rps": 25.000123456789,
    "loop": {"rate_hz": 10000.0, "jitter_p99_us": math.nan, "ticks": 2**40},
    "faults": [{"kind": "imu", "cause": "IMU lost: pl IMU: no samples for 1.16 s \u00b5", "t": -math.inf}],
    "recording": None,
    "stale": False,
}


def _answer(value: object, line: bytes, limits: Limits = UNLIMITED) -> bytes | None:
    async def status() -> object:
        return value

    async def speed(rps: float) -> dict[str, float]:
        return {"rps": rps}

    d = Dispatcher({"status": status, "speed": speed}, limits)
    return asyncio.run(d.handle_line(line, set()))


def test_an_encoded_result_answers_as_the_dict_would() -> None:
    for line in (
        b'{"jsonrpc":"2.0","id":7,"method":"status"}',
        b'{"jsonrpc":"2.0","id":"a\\"b","method":"status"}',
        b'[{"jsonrpc":"2.0","id":1,"method":"status"},{"jsonrpc":"2.0","id":2,"method":"speed",'
        b'"params":{"rps":2.5}},{"jsonrpc":"2.0","method":"status"},{"jsonrpc":"2.0","id":3,"method":"status"}]',
    ):
        as_dict = _answer(STATUS, line)
        encoded = _answer(Encoded(STATUS), line)
        assert as_dict is not None and encoded is not None
        assert encoded.endswith(b"\n") and encoded.count(b"\n") == 1
        assert json.loads(encoded) == json.loads(as_dict), line
    reply = json.loads(_answer(Encoded(STATUS), b'{"jsonrpc":"2.0","id":7,"method":"status"}') or b"")
    assert reply["result"]["loop"]["jitter_p99_us"] is None  # NaN → null, checked once at Encoded
    assert reply["result"]["faults"][0]["t"] is None


def test_an_encoded_result_is_still_bound_by_the_reply_size() -> None:
    limits = replace(UNLIMITED, max_reply_bytes=100)
    got = json.loads(_answer(Encoded(STATUS), b'{"jsonrpc":"2.0","id":7,"method":"status"}', limits) or b"")
    assert got["error"]["code"] == -32003 and got["id"] == 7
