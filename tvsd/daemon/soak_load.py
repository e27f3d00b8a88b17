"""The soak's load and probes (tvsd.daemon.soak): CPU hogs that die with the soak, RPC clients
polling `status`, oversized batches, the machine's floor beside the daemon, recording exports."""

from __future__ import annotations

import ctypes
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tvsd.rpc.client import RpcClient

BATCH_CALLS = 500  # one of 300 stalled the event loop 1.8 s before the API's limits; 500 answered 11.8 MB
HOG = "while True: pass"
PR_SET_PDEATHSIG = 1


def die_with_parent(sig: int) -> Callable[[], None]:
    """preexec_fn: the child gets `sig` when this process dies (a SIGKILLed soak leaves no hog)."""

    def setup() -> None:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, sig)

    return setup


@dataclass
class Load:
    """What the clients saw, filled by their threads."""

    stop: threading.Event = field(default_factory=threading.Event)
    lock: threading.Lock = field(default_factory=threading.Lock)
    status_calls: int = 0
    client_errors: dict[str, int] = field(default_factory=dict)
    batches: int = 0
    batch_answers: dict[str, int] = field(default_factory=dict)  # error code or "reply"
    batch_reply_bytes_max: int = 0
    batch_reply_s_max: float = 0.0

    def error(self, what: str) -> None:
        with self.lock:
            self.client_errors[what] = self.client_errors.get(what, 0) + 1


def hammer(sock: Path, load: Load) -> None:
    while not load.stop.is_set():
        try:
            with RpcClient(sock, timeout=30.0) as c:
                while not load.stop.is_set():
                    c.call("status")
                    with load.lock:
                        load.status_calls += 1
        except Exception as exc:  # counted; connect again (a refused client, a timeout)
            load.error(type(exc).__name__)
            load.stop.wait(0.05)


def batch(sock: Path, load: Load) -> None:
    """One oversized batch line; what came back (an error code, or a reply) and its size."""
    line = json.dumps([{"jsonrpc": "2.0", "id": i, "method": "status"} for i in range(BATCH_CALLS)])
    t0 = time.monotonic()
    got = b""
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(30)
            s.connect(str(sock))
            s.sendall(line.encode() + b"\n")
            while not got.endswith(b"\n"):
                chunk = s.recv(1 << 20)
                if not chunk:
                    break
                got += chunk
    except OSError as exc:
        load.error(f"batch {type(exc).__name__}")
        return
    try:
        reply = json.loads(got)
        answer = str(reply["error"]["code"]) if isinstance(reply, dict) and "error" in reply else "reply"
    except (ValueError, KeyError, TypeError):
        answer = "not JSON" if got else "closed"
    with load.lock:
        load.batches += 1
        load.batch_answers[answer] = load.batch_answers.get(answer, 0) + 1
        load.batch_reply_bytes_max = max(load.batch_reply_bytes_max, len(got))
        load.batch_reply_s_max = max(load.batch_reply_s_max, time.monotonic() - t0)


def floor_probe(seconds: float, period_s: float, out: dict[str, Any]) -> None:
    """The machine's floor beside the daemon: same period, same priority, the other core."""
    from tvsd.control import latency as L
    from tvsd.control.runner import request_realtime

    cpus = sorted(os.sched_getaffinity(0))
    other = cpus[0] if len(cpus) > 1 else None  # the control thread takes the last one
    ints, hist = L.run_floor(seconds, period_s, lambda: request_realtime(cpu=other, lock=False))
    out["floor"] = L.jitter(ints, hist)


def export(rec: Path, results: list[dict[str, Any]]) -> None:
    out = rec.with_name(rec.name + ".csv")
    r = subprocess.run(
        [sys.executable, "-m", "tvsd.cli.main", "export", str(rec), "--csv", str(out)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    ok = r.returncode == 0 and out.exists()
    gaps = 0
    if ok:
        with out.open() as f:
            gaps = sum(1 for line in f if line.startswith("# gap_"))
    results.append({"recording": rec.name, "ok": ok, "gaps": gaps, "error": r.stderr.strip()[-300:]})


def start_hogs(n: int) -> list[subprocess.Popen[bytes]]:
    """`n` busy processes at normal priority; each gets SIGKILL if this process dies."""
    return [
        subprocess.Popen([sys.executable, "-c", HOG], preexec_fn=die_with_parent(signal.SIGKILL))
        for _ in range(n)
    ]
