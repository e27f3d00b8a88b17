"""The SIL bus thread's service time per request, and what it is made of.

`TimedBus` wraps the bus thread's handler (tvsd.hw.i2c_remote.BusHandler over the twins'
SimI2CBus) and times each request from its bytes read to its reply made. It splits that time
three ways: the modelled bit time (the bus's bits for the request at its clock rate, which the
transfer sleeps: the part a real bus takes too), the bus thread's own CPU (thread_time: the twins'
work and the wire's Python), and the rest, waiting (for the GIL beside the plant's thread, a
sleep's overshoot, a run queue). Mean, p99 and max each; the p99s from fixed 0.1 ms bins.
"""

from __future__ import annotations

import time
from typing import Any

SERVICE_EDGES_MS = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
BIN_MS = 0.1
BINS = 2000  # 0..200 ms in 0.1 ms bins; past it, the last bin (p99 then reads "≥ 200")


class _Histogram:
    def __init__(self) -> None:
        self.counts = [0] * (BINS + 1)
        self.n = 0
        self.sum = self.max = 0.0

    def add(self, ms: float) -> None:
        self.counts[min(max(int(ms / BIN_MS), 0), BINS)] += 1
        self.n += 1
        self.sum += ms
        self.max = max(self.max, ms)

    def mean(self) -> float:
        return self.sum / self.n if self.n else 0.0

    def quantile(self, q: float) -> float:
        """The upper edge of the bin holding the q-quantile (0 with no data)."""
        need, seen = q * self.n, 0
        for i, c in enumerate(self.counts):
            seen += c
            if c and seen >= need:
                return (i + 1) * BIN_MS
        return 0.0


class TimedBus:
    """The bus thread's handler, each request timed; see the module doc."""

    def __init__(self, handle: Any) -> None:
        self.handle = handle
        self._bus = getattr(handle, "bus", None)  # a SimI2CBus: its bits and rate give the bit time
        self.requests = 0
        self.over = [0] * len(SERVICE_EDGES_MS)
        self.service, self.excess = _Histogram(), _Histogram()
        self.cpu_sum_ms = self.bit_sum_ms = 0.0
        # the twins' share of that CPU: their sample generations and the CPU those took
        self._twins = list(getattr(self._bus, "devices", {}).values())
        self.twin_cpu_sum_ms, self.twin_generations = 0.0, 0

    def _bits(self) -> int:
        return int(getattr(self._bus, "bits", 0))

    def _twin_work(self) -> tuple[float, int]:
        return (
            sum(float(getattr(d, "cpu_s", 0.0)) for d in self._twins),
            sum(int(getattr(d, "generations", 0)) for d in self._twins),
        )

    def __call__(self, op: int, payload: bytes) -> bytes:
        t0, c0, b0 = time.monotonic(), time.thread_time(), self._bits()
        w0 = self._twin_work()
        try:
            out: bytes = self.handle(op, payload)
            return out
        finally:
            ms = 1e3 * (time.monotonic() - t0)
            hz = getattr(self._bus, "bus_hz", None)
            bit_ms = 1e3 * (self._bits() - b0) / hz if hz else 0.0
            self.requests += 1
            self.service.add(ms)
            self.excess.add(ms - bit_ms)
            self.bit_sum_ms += bit_ms
            self.cpu_sum_ms += 1e3 * (time.thread_time() - c0)
            w1 = self._twin_work()
            self.twin_cpu_sum_ms += 1e3 * (w1[0] - w0[0])
            self.twin_generations += w1[1] - w0[1]
            for i, edge in enumerate(SERVICE_EDGES_MS):
                if ms > edge:
                    self.over[i] += 1

    def report(self) -> dict[str, Any]:
        n = max(self.requests, 1)
        return {
            "requests": self.requests,
            "service_mean_ms": round(self.service.mean(), 3),
            "service_p99_ms": round(self.service.quantile(0.99), 1),
            "service_max_ms": round(self.service.max, 3),
            "service_over_ms": {f"{e:g}": c for e, c in zip(SERVICE_EDGES_MS, self.over, strict=True)},
            "bit_time_mean_ms": round(self.bit_sum_ms / n, 3),
            "excess_mean_ms": round(self.excess.mean(), 3),  # service beyond the bit time
            "excess_p99_ms": round(self.excess.quantile(0.99), 1),
            "cpu_mean_ms": round(self.cpu_sum_ms / n, 3),  # the bus thread's own; the rest waits
            "twin_cpu_mean_ms": round(self.twin_cpu_sum_ms / n, 3),  # of which the twins' sampling
            "twin_generations_per_request": round(self.twin_generations / n, 3),
        }
