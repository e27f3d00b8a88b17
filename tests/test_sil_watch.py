"""The stall watch (tvsd/sim/sil_watch.py) sees a process stand still and says how."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import wait_for

from tvsd.sim.sil_watch import ENV_STALLS

CHILD = """
import threading, time
from tvsd.sim.sil_watch import StallWatch
w = StallWatch()
w.start()
print("up", flush=True)
threading.Event().wait(60)
"""


def _report(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def test_a_stopped_process_is_one_stall_in_which_no_thread_ran(tmp_path: Path) -> None:
    """A process stopped (SIGSTOP) for 0.3 s: its watch (ticks of 10 ms) records one stall of
    at least the 0.3 s, in which no thread of it ran on a CPU or waited on a run queue for
    more than a few ms (schedstat: the kernel did not run it at all — the case of "blocked",
    unlike a thread holding the GIL, which runs through the stall). Tolerances: the stall's
    length is ≥ the stop (a stop cannot be shorter than it was) and < stop + 1 s (a loaded
    machine delays the wake-up after SIGCONT by up to that); each thread's CPU time in the
    window ≤ 20 ms (its last tick's work before the stop and its first after)."""
    path = tmp_path / "stalls.json"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD],
        stdout=subprocess.PIPE,
        env={**os.environ, ENV_STALLS: str(path)},
    )
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == b"up"
        wait_for(lambda: _report(path).get("ticks", 0) > 5, 30.0, "the watch ticking")
        os.kill(child.pid, signal.SIGSTOP)
        time.sleep(0.3)
        os.kill(child.pid, signal.SIGCONT)
        rep = wait_for(lambda: _report(path), 30.0, "a stall reported", ok=lambda r: r.get("stalls", 0) >= 1)
    finally:
        child.kill()
        child.wait()
    worst = rep["worst"]
    assert 300 <= worst["ms"] < 1300, worst
    assert worst["threads"], worst
    for name, t in worst["threads"].items():
        assert t["ran_ms"] <= 20 and t["queued_ms"] <= 20, (name, t)
    assert worst["gc"] == [] and worst["plant_lag_ms"] is None


@pytest.mark.slow
def test_the_outside_sampler_sees_where_the_threads_are_while_the_process_stands(tmp_path: Path) -> None:
    """The same stop seen from outside (tvsd.sim.proc_watch): the watch's tick count stops, and
    while it does the sampler reads every thread of the stopped process — state T (stopped),
    the process's faults — at least once. Tolerances: the episode lasts ≥ the 0.3 s stop minus
    the sampler's 40 ms threshold (it is timed from the watch's last tick seen) and < stop + 1 s
    (a loaded machine's wake-up after SIGCONT)."""
    path, out = tmp_path / "stalls.json", tmp_path / "where.json"
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD], stdout=subprocess.PIPE, env={**os.environ, ENV_STALLS: str(path)}
    )
    sampler = None
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == b"up"
        wait_for(lambda: _report(path).get("watch_tid", 0), 30.0, "the watch's thread id")
        args = ["--pid", str(child.pid), "--report", str(path), "--out", str(out), "--priority", "0"]
        sampler = subprocess.Popen([sys.executable, "-m", "tvsd.sim.proc_watch", *args])
        wait_for(lambda: _report(out).get("ticks", 0) > 5, 30.0, "the sampler ticking")
        os.kill(child.pid, signal.SIGSTOP)
        time.sleep(0.3)
        os.kill(child.pid, signal.SIGCONT)
        stopped = wait_for(lambda: _stopped(_report(out)), 30.0, "an episode with the threads stopped")
    finally:
        child.kill()
        child.wait()
        if sampler is not None:
            sampler.kill()
            sampler.wait()
    ep = stopped[0]  # (the machine's load may make others, shorter: the watch is not SCHED_FIFO here)
    assert 260 <= ep["ms"] < 1300, ep
    assert "faults" in ep and ep["faults"]["majflt"] >= 0


def _stopped(rep: dict) -> list[dict]:
    """The sampler's episodes in which every thread was seen stopped (state T)."""
    return [
        e
        for e in rep.get("recent", [])
        if any({t["state"] for t in s["threads"].values()} == {"T"} for s in e["snaps"])
    ]
