"""The soak's view of where the daemon's threads were (tvsd.daemon.soak): the outside sampler
(tvsd.sim.proc_watch) started beside the daemon, and the page-fault and pressure figures of the
daemon's stall watch (tvsd.sim.sil_watch) before and after the load."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from tvsd.daemon.soak_load import die_with_parent
from tvsd.sim.proc_where import pressure_delta

CONTROL_THREAD = "tvsd-control"  # tvsd.control.runner's thread: the 10 kHz loop
WHERE_KEPT = 5  # the longest episodes in the soak's report


def start_sampler(pid: int, report: Path, out: Path) -> subprocess.Popen[bytes]:
    """The outside sampler of process `pid` (its stall watch writes `report`), killed with us."""
    cmd = [sys.executable, "-m", "tvsd.sim.proc_watch", "--pid", str(pid), "--report", str(report)]
    return subprocess.Popen(
        [*cmd, "--out", str(out)],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, preexec_fn=die_with_parent(signal.SIGTERM),
    )  # fmt: skip


def stop_sampler(proc: subprocess.Popen[bytes] | None, out: Path) -> dict[str, Any]:
    """Stop it (it writes its last report at SIGTERM) and read that report ({} if none)."""
    if proc is None:
        return {}
    with contextlib.suppress(ProcessLookupError):
        proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
    try:
        rep: dict[str, Any] = json.loads(out.read_text())
    except (OSError, ValueError):
        return {}
    return rep


def where_figures(
    before: dict[str, Any], after: dict[str, Any], sampled: dict[str, Any], t0: float, t1: float
) -> dict[str, Any]:
    """`before`/`after`: the daemon's stall-watch reports around the load; `sampled`: the outside
    sampler's. Page faults during the load (the process's; each thread's, the control thread's
    apart: the 10 kHz loop must take none), the machine's pressure stalls (µs), and the sampler's
    episodes in the load's window (the longest WHERE_KEPT, with every thread's place in them)."""
    out: dict[str, Any] = {}
    fb, fa = before.get("faults") or {}, after.get("faults") or {}
    out["soak_daemon_faults"] = {k: fa[k] - fb.get(k, 0) for k in fa} if fa and fb else None
    tb, ta = before.get("thread_faults") or {}, after.get("thread_faults") or {}
    per = {n: [v[0] - tb[n][0], v[1] - tb[n][1]] for n, v in ta.items() if n in tb}
    out["soak_daemon_thread_faults"] = per  # [minor, major] during the load, by thread name
    out["soak_control_thread_minflt"] = per.get(CONTROL_THREAD, [None])[0]
    out["soak_pressure_us"] = pressure_delta(before.get("pressure"), after.get("pressure"))
    eps = [e for e in sampled.get("recent", []) if t0 <= e.get("t0", 0.0) <= t1]
    out["soak_daemon_where_episodes"] = sampled.get("episodes")
    out["soak_daemon_where_sampler_late_max_ms"] = sampled.get("late_max_ms")
    out["soak_daemon_where"] = sorted(eps, key=lambda e: -e["ms"])[:WHERE_KEPT]
    return out
