"""A stall watchdog for the SIL devices' process (tvsd.sim.sil_process): what stood still, and why.

The process stands in for hardware: when all of it stands still (a soak saw one bus round trip
of 730 ms and the MCU's frames 725 ms late, none missing) the daemon sees a dead sensor and a
dead MCU. From inside, three causes look alike (a thread that should run, does not) and this
tells them apart after the fact, per thread, from the kernel's own accounting
(/proc/self/task/<tid>/schedstat: CPU time run and time waited on a run queue):
- a thread **ran** through the stall: it held the GIL computing (a catch-up, the collector —
  `gc` pauses are timed too); the others waited for it;
- threads **waited on a run queue**: the CPU was not theirs (higher priority threads, RT
  throttling: sched_rt_runtime_us takes SCHED_FIFO threads off for the rest of each second);
- nothing ran, nothing waited to: the process slept (blocked in the kernel: page faults, I/O).

`StallWatch(plant).start(realtime)` runs a thread that wakes every TICK_S; a wake-up later than
STALL_S past its due time is a stall, recorded with those deltas per thread (by Python name),
the collector's pauses that overlap it, the plant's lag behind its pacing line then, and where
each thread's Python stack stood when the watchdog ran again, and where each thread was in the
kernel then (tvsd.sim.proc_where: state, wchan, system call, kernel stack; a thread still blocked
when the watch runs again shows what held it) with its page faults since the last second's
sample. Every second: the process's and each thread's page faults and the machine's pressure
totals (/proc/pressure). `report()` is JSON: the count,
the worst, the last STALLS_KEPT. With $TVSD_SIL_STALLS naming a file, it is rewritten every
second (the soak reads it: its daemon's SIL process inherits the environment).
"""

from __future__ import annotations

import contextlib
import gc
import json
import mmap
import os
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tvsd.sim import proc_where as W

ENV_STALLS = "TVSD_SIL_STALLS"
TICK_S = 0.01
STALL_S = 0.05  # late by this much: a stall (the FIFO of a 1 kHz MPU6050 holds 85 ms)
STALLS_KEPT = 20
GC_KEPT = 64
EXPORT_S = 1.0
# The watch's tick count, stored each tick in `<export_to>.beat` (a shared file mapping): an
# outside sampler (tvsd.sim.proc_watch) sees it stop while the process stands
BEAT_SUFFIX, BEAT_BYTES = ".beat", 8
# Under --realtime: above the process's other threads (plant 30, bus 45), so that its own
# wake-up is late only when the whole process is held off or the GIL is held.
WATCH_PRIORITY = 46


def _schedstat() -> dict[int, tuple[int, int]]:
    """Per thread of this process: (ns run on a CPU, ns waited on a run queue)."""
    out: dict[int, tuple[int, int]] = {}
    with contextlib.suppress(OSError):
        for tid in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{tid}/schedstat", "rb") as f:
                    run, wait, _ = f.read().split()
            except (OSError, ValueError):
                continue  # the thread ended
            out[int(tid)] = (int(run), int(wait))
    return out


class StallWatch:
    """The watchdog thread; `plant` (a McuPlant, or None) for its lag behind the pacing line."""

    def __init__(
        self,
        plant: Any = None,
        tick_s: float = TICK_S,
        stall_s: float = STALL_S,
        export_to: str | None = None,
        extra: Callable[[], dict[str, Any]] | None = None,
    ) -> None:
        """`export_to`: the file to rewrite every second (default: $TVSD_SIL_STALLS, if set);
        `extra()`: more figures for the report."""
        self.plant, self.tick_s, self.stall_s, self.extra = plant, tick_s, stall_s, extra
        self.export_to = os.environ.get(ENV_STALLS, "").strip() if export_to is None else export_to
        self.stalls = 0
        self.worst: dict[str, Any] | None = None
        self.recent: deque[dict[str, Any]] = deque(maxlen=STALLS_KEPT)
        self.late_max_ms = 0.0
        self.ticks = 0
        # the plant's thread (SCHED_FIFO 30, below the bus thread and this one) behind its
        # pacing line, looked at every tick: late MCU frames with this thread on time
        self.plant_lag_max_ms = 0.0
        self.plant_lag_max_t = 0.0
        self.gc_max_ms = 0.0
        self.gc_pauses: deque[tuple[float, float, int]] = deque(maxlen=GC_KEPT)  # (start, end, gen)
        self._gc_t0 = 0.0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.realtime = "not requested"
        self.watch_tid = 0
        # each second: {tid: (state, minflt, majflt)}, the process's faults, the machine's pressure
        self._tstat: dict[int, tuple[str, int, int]] = {}
        self.faults: dict[str, int] | None = None
        self.pressure: dict[str, Any] | None = None

    # --- the collector's pauses ---------------------------------------------------------------
    def _gc(self, phase: str, info: dict[str, Any]) -> None:
        now = time.monotonic()
        if phase == "start":
            self._gc_t0 = now
        else:
            self.gc_pauses.append((self._gc_t0, now, int(info.get("generation", -1))))
            self.gc_max_ms = max(self.gc_max_ms, 1e3 * (now - self._gc_t0))

    # --- the thread -----------------------------------------------------------------------------
    def start(self, realtime: bool = False, priority: int = WATCH_PRIORITY) -> threading.Thread:
        gc.callbacks.append(self._gc)
        th = threading.Thread(target=self._run, args=(realtime, priority), name="sil-watch", daemon=True)
        th.start()
        return th

    def stop(self) -> None:
        self._stop.set()
        with contextlib.suppress(ValueError):
            gc.callbacks.remove(self._gc)

    def _run(self, realtime: bool, priority: int) -> None:
        if realtime:
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
                self.realtime = f"granted (priority {priority})"
            except OSError as exc:
                self.realtime = f"refused: {exc.strerror or exc}"
        target = Path(self.export_to) if self.export_to else None
        self.watch_tid = threading.get_native_id()
        beat = self._beat(target)
        self._sample()
        prev_stat, prev_now = _schedstat(), time.monotonic()
        due = prev_now + self.tick_s
        next_export = due + EXPORT_S
        while not self._stop.is_set():
            time.sleep(max(due - time.monotonic(), 0.0))
            now = time.monotonic()
            stat = _schedstat()
            late = now - due
            self.ticks += 1
            if beat is not None:
                beat[:BEAT_BYTES] = self.ticks.to_bytes(BEAT_BYTES, "little")
            self.late_max_ms = max(self.late_max_ms, 1e3 * late)
            if late > self.stall_s:
                self._record(prev_now, now, prev_stat, stat)
            prev_stat, prev_now = stat, now
            lag = self._plant_lag_ms(now)
            if lag is not None and lag > self.plant_lag_max_ms:
                self.plant_lag_max_ms, self.plant_lag_max_t = lag, now
            due = max(due + self.tick_s, now)  # after a stall: from now, no burst of ticks
            if now >= next_export or self._stop.is_set():
                self._sample()
                if target is not None:
                    self._export(target)
                next_export = now + EXPORT_S
        if target is not None:
            self._export(target)

    @staticmethod
    def _beat(target: Path | None) -> mmap.mmap | None:
        """The tick count's shared mapping beside the report (None: no report, or no file)."""
        if target is None:
            return None
        try:
            with target.with_name(target.name + BEAT_SUFFIX).open("w+b") as f:
                f.truncate(BEAT_BYTES)
                return mmap.mmap(f.fileno(), BEAT_BYTES)
        except OSError:
            return None

    def _sample(self) -> None:
        """The per-second sample: page faults (each thread's, the process's) and pressure."""
        tstat = {}
        for tid in W.tids():
            st = W.task_stat("self", tid)
            if st is not None:
                tstat[tid] = st
        faults, pressure = W.process_faults(), W.pressure()
        with self._lock:
            self._tstat, self.faults, self.pressure = tstat, faults, pressure

    def _where(self, names: dict[int, str]) -> dict[str, Any]:
        """Each thread of the process in the kernel now, with its page faults since the last
        per-second sample (`minflt_since`, `majflt_since`)."""
        out = {}
        for tid in W.tids():
            w = W.where("self", tid)
            if w is None:
                continue
            old = self._tstat.get(tid)
            if old is not None:
                w["minflt_since"], w["majflt_since"] = w["minflt"] - old[1], w["majflt"] - old[2]
            out[names.get(tid, str(tid))] = w
        return out

    def _record(
        self, t0: float, t1: float, before: dict[int, tuple[int, int]], after: dict[int, tuple[int, int]]
    ) -> None:
        """One stall: the window (t0, t1] between the watchdog's last two runs."""
        names = {t.native_id: t.name for t in threading.enumerate() if t.native_id is not None}
        kernel = self._where(names)  # first: a thread still blocked now shows what held it
        frames = sys._current_frames()
        stacks = {}
        for t in threading.enumerate():
            f = frames.get(t.ident or -1)
            where: list[str] = []
            while f is not None and len(where) < 4:
                where.append(f"{Path(f.f_code.co_filename).name}:{f.f_lineno} {f.f_code.co_name}")
                f = f.f_back
            stacks[t.name] = where
        threads = {}
        for tid, (run, wait) in after.items():
            r0, w0 = before.get(tid, (run, wait))
            threads[names.get(tid, str(tid))] = {
                "ran_ms": round((run - r0) / 1e6, 2),
                "queued_ms": round((wait - w0) / 1e6, 2),
            }
        gc_in = [
            {"ms": round(1e3 * (e - s), 2), "gen": g} for s, e, g in list(self.gc_pauses) if e > t0 and s < t1
        ]
        lag_ms = self._plant_lag_ms(t1)
        entry = {
            "t": round(t1, 3),
            "ms": round(1e3 * (t1 - t0), 2),
            "threads": threads,
            "gc": gc_in,
            "plant_lag_ms": lag_ms,
            "stacks_after": stacks,
            "where_after": kernel,
            "faults": W.process_faults(),
            "pressure": W.pressure(),
        }
        with self._lock:
            self.stalls += 1
            self.recent.append(entry)
            if self.worst is None or entry["ms"] > self.worst["ms"]:
                self.worst = entry

    def _plant_lag_ms(self, now: float) -> float | None:
        """How far (wall ms) the plant's time is behind its pacing line at `now`."""
        plant = self.plant
        if plant is None or plant.pacing.feeds == 0:
            return None
        p = plant.pacing
        return round(1e3 * ((p.sim0 + (now - p.wall0) * plant.speed) - plant.t) / plant.speed, 2)

    def report(self) -> dict[str, Any]:
        with self._lock:
            return {
                "ticks": self.ticks,
                "tick_ms": 1e3 * self.tick_s,
                "stall_over_ms": 1e3 * self.stall_s,
                "stalls": self.stalls,
                "late_max_ms": round(self.late_max_ms, 2),
                "gc_max_ms": round(self.gc_max_ms, 2),
                "plant_lag_max_ms": self.plant_lag_max_ms,
                "plant_lag_max_t": round(self.plant_lag_max_t, 3),
                "realtime": self.realtime,
                "watch_tid": self.watch_tid,
                "tids": {t.name: t.native_id for t in threading.enumerate()},
                "faults": self.faults,
                "thread_faults": self._thread_faults(),
                "pressure": self.pressure,
                "worst": self.worst,
                "recent": list(self.recent),
                **(self.extra() if self.extra is not None else {}),
            }

    def _thread_faults(self) -> dict[str, list[int]]:
        """[minor, major] page faults of each thread so far, by name (the lock held)."""
        names = {t.native_id: t.name for t in threading.enumerate()}
        return {names.get(tid, str(tid)): [st[1], st[2]] for tid, st in self._tstat.items()}

    def _export(self, target: Path) -> None:
        tmp = target.with_name(target.name + ".tmp")
        with contextlib.suppress(OSError):
            tmp.write_text(json.dumps(self.report()))
            tmp.replace(target)
