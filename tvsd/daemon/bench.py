"""Benchmark: latency from optical pulse to point on the API, with the daemon on the SIL plant.

A real tvsd process on a temporary socket spins to 25 rev/s and scans; a client subscribed to the
point stream takes time.monotonic() − t_mono of each point on receipt (t_mono: the optical pulse's
host time, CLOCK_MONOTONIC, the same clock on this machine).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tvsd.daemon.state import DaemonState
from tvsd.errors import DeviceError
from tvsd.rpc.client import RpcClient


def bench_point_latency(points: int = 200, rps: float = 25.0, idle_s: float = 20.0) -> dict[str, float]:
    """Pulse → point latency on the API, and what the SIL daemon costs while it scans: first
    `idle_s` with no client but this one (asking nothing), then with a `points` subscriber."""
    with tempfile.TemporaryDirectory() as tmp:
        sock = Path(tmp) / "tvsd.sock"
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tvsd.daemon.main",
                "--sil",
                "--realtime",  # SCHED_FIFO when permitted (root, CAP_SYS_NICE); says so when not
                "--socket",
                str(sock),
                "--data-dir",
                str(Path(tmp) / "data"),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + 60
            while not sock.exists() and time.monotonic() < deadline:
                time.sleep(0.1)
            with RpcClient(sock) as ctl:
                while ctl.call("status")["state"] == DaemonState.STARTING:  # type: ignore[index]
                    time.sleep(0.1)
                _spin_up(ctl, rps)
                ctl.call("scan_start")
                idle = _idle_scan_cpu(proc.pid, ctl, idle_s)
                sample = ctl.call("status")
                before = sample["loop"]  # type: ignore[index]
                cpu0, t0 = _cpu_s(proc.pid), time.monotonic()
                lat: list[float] = []
                untimed = 0
                with RpcClient(sock) as sub:
                    for msg in sub.subscribe("points"):
                        for point in msg if isinstance(msg, list) else [msg]:
                            t_mono = point["t_mono"]  # type: ignore[index]
                            if t_mono is None:  # no MCU clock sync yet: no host time to take
                                untimed += 1
                                continue
                            lat.append(time.monotonic() - float(t_mono))
                        if len(lat) >= points or untimed >= 3 * points:  # no clock sync: stop
                            break
                cpu_pct = 100 * (_cpu_s(proc.pid) - cpu0) / (time.monotonic() - t0)
                after = ctl.call("status")["loop"]  # type: ignore[index]
                missed = (after["missed_ticks"] - before["missed_ticks"]) / (after["ticks"] - before["ticks"])
                ctl.call("shutdown")
        finally:
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
    ms = np.asarray(lat) * 1e3 if lat else np.full(1, np.nan)
    return {
        **idle,
        **bench_status_reply(sample),
        "api_point_latency_p50_ms": float(np.median(ms)),
        "api_point_latency_p99_ms": float(np.percentile(ms, 99)),
        "api_point_latency_max_ms": float(ms.max()),
        "api_points": float(len(lat)),
        "api_points_untimed": float(untimed),
        "api_rps": rps,
        # the whole SIL process: control thread, link, virtual MCU, plant, IMU twins, asyncio
        "sil_daemon_cpu_pct_of_one_core": round(cpu_pct, 1),
        "sil_daemon_missed_tick_fraction": round(missed, 4),
    }


def bench_status_reply(status: object, n: int = 2000) -> dict[str, float]:
    """What one `status` call holds the event loop for, served from the API's reused status
    (tvsd.daemon.api: one build per 20 ms), in µs: the dispatcher's whole path (decode, bind,
    call, reply) for a real status taken from the SIL daemon, returned as a dict (checked and
    encoded for every reply, as before) and as `Encoded` (checked and encoded once per build)."""
    import asyncio

    from tvsd.daemon.rpc.dispatch import Dispatcher
    from tvsd.daemon.rpc.limits import UNLIMITED
    from tvsd.rpc.protocol import Encoded

    line = b'{"jsonrpc":"2.0","id":12345,"method":"status"}'

    async def per_call(value: object) -> float:
        async def method() -> object:
            return value

        d = Dispatcher({"status": method}, UNLIMITED)
        best = float("inf")
        for _ in range(3):  # best of 3: the machine is shared
            t0 = time.perf_counter()
            for _ in range(n):
                await d.handle_line(line, set())
            best = min(best, (time.perf_counter() - t0) / n)
        return best * 1e6

    async def both() -> tuple[float, float]:
        # The build itself (Encoded(...)) once per 20 ms is not in either figure.
        return await per_call(status), await per_call(Encoded(status))

    as_dict, encoded = asyncio.run(both())
    return {
        "api_status_reply_bytes": float(len(Encoded(status).text)),
        "api_status_reply_us_dict": round(as_dict, 1),
        "api_status_reply_us_encoded": round(encoded, 1),
    }


def _spin_up(ctl: RpcClient, rps: float, timeout_s: float = 120.0) -> None:
    """Speed `rps` reached; a fault on the way (a loaded machine's stall tripping the SIL
    firmware's watchdog) is cleared and the speed asked again, as the soak does."""
    deadline = time.monotonic() + timeout_s
    ctl.call("speed", rps=rps)
    while True:
        st = ctl.call("status")
        if abs(float(st["rps"]) - rps) <= 0.5:  # type: ignore[index]
            return
        if time.monotonic() > deadline:
            raise DeviceError(f"the SIL daemon did not reach {rps:g} rev/s in {timeout_s:g} s: {st}")
        if st["state"] == DaemonState.FAULT:  # type: ignore[index]
            ctl.call("faults_clear")
            ctl.call("speed", rps=rps)
        time.sleep(0.2)


def _idle_scan_cpu(pid: int, ctl: RpcClient, seconds: float) -> dict[str, float]:
    """CPU of the event loop's thread (the daemon's main thread) and of the whole process over
    `seconds` of scanning with no client asking anything, after 3 s to settle. Not timed in
    wall clock: the CPU time each thread was charged (/proc), so a loaded machine slows it but
    does not inflate it."""
    time.sleep(3.0)
    before = ctl.call("status")
    loop0, all0, t0 = _cpu_s(pid, pid), _cpu_s(pid), time.monotonic()
    time.sleep(seconds)
    loop1, all1, t1 = _cpu_s(pid, pid), _cpu_s(pid), time.monotonic()
    after = ctl.call("status")
    points = after["points"]  # type: ignore[index]
    return {
        "idle_scan_loop_cpu_pct": round(100 * (loop1 - loop0) / (t1 - t0), 1),
        "idle_scan_process_cpu_pct": round(100 * (all1 - all0) / (t1 - t0), 1),
        "idle_scan_points_per_s": round((points["total"] - before["points"]["total"]) / (t1 - t0), 1),  # type: ignore[index]
        "idle_scan_compensated": float(bool(points.get("compensated"))),
        "idle_scan_faults": float(sum(after["fault_counts"].values()) - sum(before["fault_counts"].values())),  # type: ignore[index]
    }


def _cpu_s(pid: int, tid: int | None = None) -> float:
    """User + system CPU seconds of a process, or of its thread `tid` (/proc/.../stat fields 14
    and 15)."""
    stat = Path(f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat")
    fields = stat.read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
