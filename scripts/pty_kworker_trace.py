"""How long the kernel's tty flip-buffer work waits and runs, per pty port (root, tracefs).

Every byte written to a pty reaches the other side's reader through `flush_to_ldisc`, queued on
the unbound workqueue and run by a normal-priority kworker (docs/measurements/siltiming.md).
This traces that work (workqueue_queue_work / execute_start / execute_end, filtered on the
function, in its own tracefs instance on CLOCK_MONOTONIC, so the times compare with
time.monotonic() and the heartbeats' host_us) until SIGTERM/SIGINT, and writes per work item
(one per pty side): who queued it (the writer's thread), the wait queue -> start and the run
start -> end (histograms, max), and the worst waits with their times.

    sudo python scripts/pty_kworker_trace.py OUT.json [--keep 40]

Measurement only: nothing in tvsd uses it.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import json
import os
import re
import signal
import sys
from collections import Counter, defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

TRACEFS = Path("/sys/kernel/tracing")
INSTANCE = "tvsd-pty-kworker"
EVENTS = ("workqueue_queue_work", "workqueue_execute_start", "workqueue_execute_end")
EDGES_MS = (0.1, 0.5, 1, 2, 5, 10, 20, 40, 75, 100, 200, 500, 1000)
LINE = re.compile(
    r"^\s*(?P<task>.+?)-(?P<pid>\d+)\s+\[\d+\]\s+\S+\s+(?P<ts>[\d.]+): (?P<ev>\w+): (?P<rest>.*)$"
)
WORK = re.compile(r"work struct[= ](?P<w>[0-9a-f]+)")


class Stage:
    def __init__(self) -> None:
        self.n, self.max_ms, self.hist = 0, 0.0, [0] * (len(EDGES_MS) + 1)

    def add(self, ms: float) -> None:
        self.n += 1
        self.max_ms = max(self.max_ms, ms)
        self.hist[bisect.bisect_left(EDGES_MS, ms)] += 1

    def as_dict(self) -> dict[str, Any]:
        labels = [f"<={e:g}" for e in EDGES_MS] + [f">{EDGES_MS[-1]:g}"]
        return {"n": self.n, "max_ms": round(self.max_ms, 3),
                "hist_ms": {k: v for k, v in zip(labels, self.hist, strict=True) if v}}  # fmt: skip


def setup() -> Path:
    if not (TRACEFS / "instances").is_dir():
        raise SystemExit(
            "pty_kworker_trace: tracefs not mounted (mount -t tracefs nodev /sys/kernel/tracing)"
        )
    inst = TRACEFS / "instances" / INSTANCE
    if not inst.exists():
        inst.mkdir()
    (inst / "trace_clock").write_text("mono")
    (inst / "buffer_size_kb").write_text("8192")
    for ev in EVENTS:
        d = inst / "events" / "workqueue" / ev
        (d / "filter").write_text("function.function == flush_to_ldisc")
        (d / "enable").write_text("1")
    return inst


def teardown(inst: Path) -> None:
    with contextlib.suppress(OSError):
        for ev in EVENTS:
            (inst / "events" / "workqueue" / ev / "enable").write_text("0")
        inst.rmdir()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--keep", type=int, default=40)
    args = ap.parse_args()
    inst = setup()

    def on_signal(*_: object) -> None:
        raise KeyboardInterrupt  # out of a blocked read of trace_pipe

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    queued: dict[str, tuple[float, str]] = {}
    started: dict[str, float] = {}
    wait: dict[str, Stage] = defaultdict(Stage)
    run: dict[str, Stage] = defaultdict(Stage)
    writers: dict[str, Counter[str]] = defaultdict(Counter)
    worst: list[tuple[float, dict[str, Any]]] = []
    lost = 0
    fd = os.open(inst / "trace_pipe", os.O_RDONLY)
    pending = b""

    def lines() -> Iterator[str]:
        nonlocal pending
        while True:
            chunk = os.read(fd, 1 << 16)  # what is there (blocks while nothing is)
            *done, pending = (pending + chunk).split(b"\n")
            for raw in done:
                yield raw.decode(errors="replace")

    try:
        for line in lines():
            if "LOST" in line:
                lost += 1
                continue
            m = LINE.match(line)
            w = WORK.search(line)
            if m is None or w is None:
                continue
            ts, ev, work = float(m["ts"]), m["ev"], w["w"]
            if ev == "workqueue_queue_work":
                who = f"{m['task'].strip()}-{m['pid']}"
                queued[work] = (ts, who)
                writers[work][who] += 1
            elif ev == "workqueue_execute_start" and work in queued:
                q, who = queued.pop(work)
                ms = 1e3 * (ts - q)
                wait[work].add(ms)
                started[work] = ts
                item = {"work": work, "queued": round(q, 6), "start": round(ts, 6), "wait_ms": round(ms, 3),
                        "queued_by": who, "run_by": f"{m['task'].strip()}-{m['pid']}"}  # fmt: skip
                if len(worst) < args.keep or ms > worst[0][0]:
                    bisect.insort(worst, (ms, item), key=lambda x: x[0])
                    del worst[: max(len(worst) - args.keep, 0)]
            elif ev == "workqueue_execute_end" and work in started:
                run[work].add(1e3 * (ts - started.pop(work)))
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        os.close(fd)
        teardown(inst)
        rep = {
            "clock": "CLOCK_MONOTONIC s",
            "lost_lines": lost,
            "works": {
                w: {
                    "queued_by": dict(writers[w].most_common(4)),
                    "wait": wait[w].as_dict(),
                    "run": run[w].as_dict(),
                }
                for w in sorted(wait, key=lambda k: -wait[k].n)
            },
            "worst_waits": [it for _, it in sorted(worst, key=lambda x: -x[0])],
        }
        args.out.write_text(json.dumps(rep, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
