"""What one client may ask of the JSON-RPC server: `Limits` (from the config's ``daemon:`` section;
README "Daemon API limits"), the per-connection token bucket that enforces the rate, and the
-32003 error that names a limit (``error.data``: limit, value, seen)."""

from __future__ import annotations

import time
from dataclasses import dataclass

from tvsd.rpc.protocol import LIMIT_ERROR, RpcError


@dataclass(frozen=True)
class Limits:
    """What one client may ask of the server (`tvsd.daemon.rpc`); defaults as the config's."""

    max_batch: int = 50  # requests in one batch line
    max_reply_bytes: int = 1 << 20  # one reply line (a status is ~2-5 KB)
    rate_per_s: float = 50.0  # requests per second per connection, sustained
    burst: int = 50  # requests a connection may send at once before the rate applies
    max_concurrent: int = 8  # a batch's requests in flight at once
    max_clients: int = 64  # connections at once
    # requests per second from all connections together: with 64 clients at 50/s each the event
    # loop would be busy all the time, and the MCU link's I/O thread waits for its GIL
    rate_total_per_s: float = 400.0

    def __post_init__(self) -> None:
        if self.burst < self.max_batch:
            raise ValueError(f"burst {self.burst} must be at least max_batch {self.max_batch}")


UNLIMITED = Limits(max_batch=1000, max_reply_bytes=1 << 30, rate_per_s=1e9, burst=10**9, max_clients=10**4,
    rate_total_per_s=1e12,
)


def limit_error(name: str, value: float, seen: float, text: str) -> RpcError:
    return RpcError(LIMIT_ERROR, text, {"limit": name, "value": value, "seen": seen})


class TokenBucket:
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
