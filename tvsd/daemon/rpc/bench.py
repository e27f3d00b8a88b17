"""Round-trip latency of the JSON-RPC server over its real socket (README: RPC `status` round trip)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from tvsd.daemon.rpc.limits import UNLIMITED
from tvsd.daemon.rpc.server import ThreadedRpcServer


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
