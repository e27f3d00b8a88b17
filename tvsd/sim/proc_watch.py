"""Where a process's threads are WHILE it stands still, seen from outside it.

A stall watch (tvsd.sim.sil_watch) inside the process stands still with it: it can say how long
and, after, who ran or queued, but not where the threads were while blocked. This sampler, its
own process (SCHED_FIFO `--priority` when permitted), looks every TICK_S at the watch's tick
count, which the watch stores in a shared file mapping (WATCH.json.beat, 8 bytes; no system call
on either side). When it has not moved for STALL_S the watch missed ≥ 3 ticks, whatever held it
(the GIL, the CPU, the kernel) and the process stands: every thread's state, wchan, system call, kernel
stack and page faults are read (tvsd.sim.proc_where; none of those files waits for the
process's memory-map lock), again every SNAP_EVERY_S while it lasts, and the episode is kept
with its length, the process's page faults and the machine's pressure totals across it.

    python -m tvsd.sim.proc_watch --pid PID --report WATCH.json --out OUT.json

WATCH.json: the process's stall-watch report (its `watch_tid` and `tids`: thread names).
OUT.json is rewritten every second and at SIGTERM; the soak (tvsd.daemon.soak) runs this beside
the daemon and reports it as `soak_daemon_where`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import mmap
import os
import signal
import time
from collections import deque
from pathlib import Path
from typing import Any

from tvsd.sim import proc_where as W
from tvsd.sim.sil_watch import BEAT_BYTES, BEAT_SUFFIX

TICK_S = 0.01
STALL_S = 0.04  # the watch's CPU time still for this long: its 10 ms ticks missed ≥ 3
SNAP_EVERY_S = 0.1
SNAPS_KEPT = 6  # per episode
EPISODES_KEPT = 20
EXPORT_S = 1.0


def _beat(path: Path) -> mmap.mmap | None:
    """The watch's tick count, mapped (None until the watch made it)."""
    try:
        with path.open("rb") as f:
            return mmap.mmap(f.fileno(), BEAT_BYTES, access=mmap.ACCESS_READ)
    except (OSError, ValueError):
        return None


def _names(report: Path) -> tuple[int, dict[int, str]]:
    """The watch thread's id and the threads' names from the process's stall-watch report."""
    try:
        rep = json.loads(report.read_text())
    except (OSError, ValueError):
        return 0, {}
    return int(rep.get("watch_tid") or 0), {int(t): n for n, t in (rep.get("tids") or {}).items() if t}


class ProcWatch:
    def __init__(self, pid: int, report: Path, tick_s: float = TICK_S, stall_s: float = STALL_S) -> None:
        self.pid, self.report_path, self.tick_s, self.stall_s = pid, report, tick_s, stall_s
        self.watch_tid, self.names = 0, dict[int, str]()
        self.episodes: deque[dict[str, Any]] = deque(maxlen=EPISODES_KEPT)
        self.count = 0
        self.worst: dict[str, Any] | None = None
        self.ticks = 0
        self.late_max_ms = 0.0  # this sampler's own wake-ups: what it could not see
        self.stop = False

    def snapshot(self) -> dict[str, Any]:
        """Every thread now, by name."""
        out = {}
        for tid in W.tids(self.pid):
            w = W.where(self.pid, tid)
            if w is not None:
                out[self.names.get(tid, str(tid))] = w
        return out

    def run(self) -> None:
        beat = None
        while (not self.watch_tid or beat is None) and not self.stop:
            self.watch_tid, self.names = _names(self.report_path)
            beat = _beat(self.report_path.with_name(self.report_path.name + BEAT_SUFFIX))
            time.sleep(0.2)
        if beat is None:
            return
        last_ns, last_moved = beat[:BEAT_BYTES], time.monotonic()
        episode: dict[str, Any] | None = None
        due = time.monotonic() + self.tick_s
        next_names = due + EXPORT_S
        while not self.stop:
            time.sleep(max(due - time.monotonic(), 0.0))
            now = time.monotonic()
            self.late_max_ms = max(self.late_max_ms, 1e3 * (now - due))
            due = max(due + self.tick_s, now)
            self.ticks += 1
            if not os.path.exists(f"/proc/{self.pid}/task/{self.watch_tid}"):
                break  # the process (or its watch) ended
            ns = beat[:BEAT_BYTES]
            if ns != last_ns:
                if episode is not None:
                    self._close(episode, now, last_moved)
                    episode = None
                last_ns, last_moved = ns, now
            elif now - last_moved >= self.stall_s:
                if episode is None:
                    episode = {
                        "t0": round(last_moved, 3),
                        "faults_before": W.process_faults(self.pid),
                        "pressure_before": W.pressure(),
                        "snaps": [],
                        "_next": now,
                    }
                if now >= episode["_next"] and len(episode["snaps"]) < SNAPS_KEPT:
                    episode["snaps"].append(
                        {"at_ms": round(1e3 * (now - last_moved), 1), "threads": self.snapshot()}
                    )
                    episode["_next"] = now + SNAP_EVERY_S
            if now >= next_names:  # threads come and go
                self.names = _names(self.report_path)[1] or self.names
                next_names = now + EXPORT_S

    def _close(self, ep: dict[str, Any], now: float, t0: float) -> None:
        """The watch ran again: the episode's length is from its last run seen to this one."""
        ep.pop("_next", None)
        ep["ms"] = round(1e3 * (now - t0), 1)
        fa, fb = W.process_faults(self.pid), ep.pop("faults_before")
        if fa and fb:
            ep["faults"] = {k: fa[k] - fb[k] for k in fa}
        ep["pressure_us"] = W.pressure_delta(ep.pop("pressure_before"), W.pressure())
        self.count += 1
        self.episodes.append(ep)
        if self.worst is None or ep["ms"] > self.worst["ms"]:
            self.worst = ep

    def report(self) -> dict[str, Any]:
        return {
            "pid": self.pid,
            "tick_ms": 1e3 * self.tick_s,
            "stall_over_ms": 1e3 * self.stall_s,
            "ticks": self.ticks,
            "late_max_ms": round(self.late_max_ms, 2),
            "episodes": self.count,
            "worst": self.worst,
            "recent": list(self.episodes),
        }


def _write(out: Path, rep: dict[str, Any]) -> None:
    tmp = out.with_name(out.name + ".tmp")
    with contextlib.suppress(OSError):
        tmp.write_text(json.dumps(rep))
        tmp.replace(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tvsd.sim.proc_watch", description=__doc__.split("\n\n")[0])
    ap.add_argument("--pid", type=int, required=True)
    ap.add_argument("--report", type=Path, required=True, help="the process's stall-watch JSON")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--priority", type=int, default=90, help="SCHED_FIFO priority (0: normal)")
    args = ap.parse_args(argv)
    if args.priority:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.priority))
    pw = ProcWatch(args.pid, args.report)

    def _stop(*_: Any) -> None:
        pw.stop = True

    signal.signal(signal.SIGTERM, _stop)
    import threading

    def _exporter() -> None:
        while not pw.stop:
            time.sleep(EXPORT_S)
            _write(args.out, pw.report())

    threading.Thread(target=_exporter, daemon=True).start()
    pw.run()
    _write(args.out, pw.report())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
