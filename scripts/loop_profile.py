"""What holds tvsd's event loop under the soak's load: wall time per callback, by what it runs.

    python scripts/loop_profile.py SECONDS OUT.json [--cprofile]

Runs `tvsctl bench --only soak`'s load (tvsd/daemon/soak.py) against a tvsd started through this
file, which times every asyncio callback (`asyncio.events.Handle._run`: reader callbacks, timers,
call_soon(_threadsafe), each step of each task) on the loop's thread with time.perf_counter and
sums them by what runs: a task by its coroutine, anything else by its function. Wall time: a
callback that waits for the GIL is charged the wait, since the loop is held as long. At the
daemon's exit it writes OUT.json, then prints the table: share of the run each holds, calls, mean,
p99 and max, callbacks over 10 / 50 ms. `--cprofile` also profiles the loop's thread with cProfile
(OUT.prof; slows Python code on that thread ~1.5x: for where time goes inside a callback, not for
the totals). py-spy could not be used for this: under the soak's hogs it fell 45 s behind in 40 s.
"""

from __future__ import annotations

import asyncio
import atexit
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

EDGES_MS = np.concatenate([[0.0], np.geomspace(0.001, 10_000, 141)])


def _name(handle: asyncio.Handle) -> str:
    cb = handle._callback  # type: ignore[attr-defined]
    owner = getattr(cb, "__self__", None)
    if isinstance(owner, asyncio.Task):
        coro = owner.get_coro()
        return f"task {getattr(coro, '__qualname__', repr(coro))}"
    return str(getattr(cb, "__qualname__", None) or getattr(type(cb), "__qualname__", repr(cb)))


def _install(out: Path, cprofile: bool) -> None:
    hist: dict[str, np.ndarray] = defaultdict(lambda: np.zeros(len(EDGES_MS), dtype=np.int64))
    total: dict[str, float] = defaultdict(float)
    worst: dict[str, float] = defaultdict(float)
    run = asyncio.events.Handle._run
    t_start = time.perf_counter()

    def timed(self: asyncio.Handle) -> None:
        t0 = time.perf_counter()
        try:
            run(self)
        finally:
            dt = time.perf_counter() - t0
            name = _name(self)
            total[name] += dt
            worst[name] = max(worst[name], dt)
            hist[name][np.searchsorted(EDGES_MS, dt * 1e3, side="right") - 1] += 1

    asyncio.events.Handle._run = timed  # type: ignore[method-assign]
    prof = None
    if cprofile:
        import cProfile

        prof = cProfile.Profile()  # this thread only: the event loop's
        prof.enable()

    def dump() -> None:
        if prof is not None:
            prof.disable()
            prof.dump_stats(str(out.with_suffix(".prof")))
        wall = time.perf_counter() - t_start
        rows = {}
        for name, h in hist.items():
            calls = int(h.sum())
            cum = np.cumsum(h)
            p99 = EDGES_MS[min(int(np.searchsorted(cum, 0.99 * calls)) + 1, len(EDGES_MS) - 1)]
            rows[name] = {
                "s": total[name], "calls": calls, "mean_ms": 1e3 * total[name] / calls, "p99_ms": float(p99),
                "max_ms": 1e3 * worst[name], "over_10ms": int(h[EDGES_MS >= 10.0].sum()),
                "over_50ms": int(h[EDGES_MS >= 50.0].sum()),
            }  # fmt: skip
        out.write_text(json.dumps({"wall_s": wall, "callbacks": rows}, indent=1))

    atexit.register(dump)


def _table(path: Path, top: int = 25) -> None:
    data = json.loads(path.read_text())
    wall, rows = data["wall_s"], data["callbacks"]
    busy = sum(r["s"] for r in rows.values())
    print(f"event loop busy {busy:.1f} s of {wall:.1f} s ({100 * busy / wall:.1f} %)")
    heads = ("% run", "calls", "mean ms", "p99 ms", "max ms", ">10ms", ">50ms")
    print(f"{'what':58s} " + " ".join(f"{h:>8s}" for h in heads))
    for name, r in sorted(rows.items(), key=lambda kv: -kv[1]["s"])[:top]:
        print(
            f"{name[:58]:58s} {100 * r['s'] / wall:8.2f} {r['calls']:8d} {r['mean_ms']:8.3f} "
            f"{r['p99_ms']:8.2f} {r['max_ms']:8.1f} {r['over_10ms']:8d} {r['over_50ms']:8d}"
        )


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--daemon":  # the soak starts tvsd through here
        out, cprofile = Path(sys.argv[2]), sys.argv[3] == "1"
        _install(out, cprofile)
        from tvsd.daemon.main import main as tvsd_main

        return tvsd_main(sys.argv[4:])
    if len(sys.argv) < 3:
        print(__doc__, file=sys.stderr)
        return 2
    from tvsd.daemon.soak import soak

    seconds, out = float(sys.argv[1]), Path(sys.argv[2]).resolve()
    cprofile = "--cprofile" in sys.argv[3:]
    res = soak(seconds, daemon=[sys.executable, __file__, "--daemon", str(out), "1" if cprofile else "0"])
    print(json.dumps(res))
    _table(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
