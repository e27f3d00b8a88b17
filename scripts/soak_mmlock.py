"""A soak with the daemon's memory-map lock traced: who calls into the kernel's memory map, who waits.

    python scripts/soak_mmlock.py OUT_DIR -- .venv/bin/tvsctl bench --only soak --seconds 150 --json

Runs the command (its stdout to OUT_DIR/soak.json), finds the daemon it starts (a descendant running
tvsd.daemon.main), and from the load's start (the outside sampler, tvsd.sim.proc_watch, appears)
until shortly before its end traces the daemon with perf (root, or perf_event_paranoid ≤ 1):

- `perf stat --per-thread`: each thread's mprotect / mmap / munmap / mremap / brk / madvise calls
  and minor page faults;
- `perf record -a` of the mmap_lock tracepoints filtered on the daemon's mm: each thread's waits
  for the daemon's memory-map lock (start_locking → acquire_returned) and its holds
  (acquire_returned → released), read and write — the daemon's threads and any other task that
  takes it (a kernel thread, a process reading the daemon's /proc files).

Writes OUT_DIR/mm.json: per thread (by its Python name from the daemon's stall-watch report), the
calls, faults, lock waits (count, sum, max, the 5 longest with the other threads holding the lock
meanwhile) and write holds (count, max); tasks outside the daemon as `comm[tid]`. A measurement
tool (docs/measurements/imureader.md), not part of the product.
"""

from __future__ import annotations

import contextlib
import json
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

SYSCALLS = ("mprotect", "mmap", "munmap", "mremap", "brk", "madvise")
EVENTS = [f"syscalls:sys_enter_{s}" for s in SYSCALLS] + ["minor-faults"]
LOCK_EVENTS = (
    "mmap_lock:mmap_lock_start_locking,mmap_lock:mmap_lock_acquire_returned,mmap_lock:mmap_lock_released"
)


def _ppid(pid: int) -> int:
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return 0
    return int(text[text.rfind(")") + 2 :].split()[1])


def _descendant(root: int, needle: str) -> int | None:
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if needle not in cmd:
            continue
        pid = int(d.name)
        p = pid
        while p > 1:
            p = _ppid(p)
            if p == root:
                return pid
    return None


def _names(pid: int) -> dict[int, str]:
    """tid → name: the daemon's stall-watch report (Python names), else the kernel's comm."""
    out: dict[int, str] = {}
    for t in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(OSError):
            out[int(t.name)] = (t / "comm").read_text().strip()
    try:
        env = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        report = next(e.split(b"=", 1)[1].decode() for e in env if e.startswith(b"TVSD_DAEMON_STALLS="))
        for name, tid in json.loads(Path(report).read_text()).get("tids", {}).items():
            if tid:
                out[int(tid)] = name
    except (OSError, StopIteration, ValueError):
        pass
    return out


def _stat(path: Path) -> dict[int, dict[str, int]]:
    """perf stat -x, --per-thread: `comm-tid,count,unit,event,...` per line."""
    out: dict[int, dict[str, int]] = {}
    for line in path.read_text().splitlines():
        f = line.split(",")
        if len(f) < 4 or "-" not in f[0]:
            continue
        tid = int(f[0].rsplit("-", 1)[1])
        try:
            n = int(float(f[1]))
        except ValueError:
            continue
        out.setdefault(tid, {})[f[3].replace("syscalls:sys_enter_", "")] = n
    return out


LINE = re.compile(
    r"^\s*(.+?)\s+(\d+)/(\d+)\s+([\d.]+):\s+mmap_lock:mmap_lock_(\w+):.*mm=(0x[0-9a-f]+).*write=(\w+)"
)


def _locks(data: Path, names: dict[int, str], daemon: int) -> list[tuple[int, float, str, bool]]:
    """The lock's events, in time order; tasks not named yet get their comm (a daemon thread
    started after the names were read: "(daemon)", else "(outside)")."""
    script = subprocess.run(
        ["perf", "script", "-i", str(data), "-F", "comm,pid,tid,time,event,trace"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    out = []
    for line in script.stdout.splitlines():
        m = LINE.match(line)
        if m:
            names.setdefault(int(m[3]), f"{m[1]}({'daemon' if int(m[2]) == daemon else 'outside'})")
            out.append((int(m[3]), float(m[4]), m[5], m[7] == "true"))
    return sorted(out, key=lambda e: e[1])


def _grown(data: Path) -> dict[int, int]:
    """KiB made accessible by mprotect, per thread (glibc growing a thread's heap)."""
    text = subprocess.run(
        ["perf", "script", "-i", str(data), "-F", "tid,trace"], capture_output=True, text=True, check=False
    ).stdout
    out: dict[int, int] = {}
    for line in text.splitlines():
        m = re.match(r"^\s*(\d+)\s+.*len: (0x[0-9a-f]+)", line)
        if m:
            out[int(m[1])] = out.get(int(m[1]), 0) + int(m[2], 16) // 1024
    return out


def _fault_where(data: Path, maps: str) -> dict[str, int]:
    """The reader's page faults by the mapping they hit (the daemon's maps at the trace's end):
    a file's name, [stack], or the anonymous mapping's size (pymalloc's arenas are 1 MiB, a
    thread arena's heap lies in a 64 MiB reservation)."""
    regions = []
    for line in maps.splitlines():
        f = line.split()
        lo, hi = (int(x, 16) for x in f[0].split("-"))
        regions.append((lo, hi, f[1], f[5] if len(f) > 5 else ""))
    text = subprocess.run(
        ["perf", "script", "-i", str(data), "-F", "addr"], capture_output=True, text=True, check=False
    ).stdout
    out: dict[str, int] = {}
    for line in text.split():
        a = int(line, 16)
        hit = next((r for r in regions if r[0] <= a < r[1]), None)
        key = (
            "unmapped at the end" if hit is None else hit[3] or f"anon {hit[2]} {(hit[1] - hit[0]) >> 10} KiB"
        )
        out[key] = out.get(key, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1])[:12])


def _mm_of(pid: int, out: Path) -> str | None:
    """The daemon's mm_struct address, from its first memory-map lock event (within 10 s)."""
    subprocess.run(
        ["perf", "record", "-q", "-o", str(out), "-e", "mmap_lock:mmap_lock_start_locking", "-p", str(pid),
         "--", "sleep", "10"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False,
    )  # fmt: skip
    text = subprocess.run(
        ["perf", "script", "-i", str(out)], capture_output=True, text=True, check=False
    ).stdout
    m = re.search(r"mm=(0x[0-9a-f]+)", text)
    return m[1] if m else None


def _analyse(events: list[tuple[int, float, str, bool]], names: dict[int, str]) -> dict[int, dict[str, Any]]:
    start: dict[int, float] = {}
    held: dict[int, tuple[float, bool]] = {}
    waits: dict[int, list[tuple[float, float]]] = {}
    holds: list[tuple[int, float, float, bool]] = []
    for tid, t, what, write in events:
        if what == "start_locking":
            start[tid] = t
        elif what == "acquire_returned":
            t0 = start.pop(tid, t)
            waits.setdefault(tid, []).append((t0, t))
            held[tid] = (t, write)
        elif what == "released" and tid in held:
            t0, w = held.pop(tid)
            holds.append((tid, t0, t, w))
    per: dict[int, dict[str, Any]] = {}
    for tid, ws in waits.items():
        d = sorted(ws, key=lambda w: w[1] - w[0], reverse=True)
        longest = []
        for t0, t1 in d[:5]:
            by = sorted(
                {
                    f"{names.get(h, h)}{' (write)' if w else ''}"
                    for h, a, b, w in holds
                    if h != tid and a < t1 and b > t0
                }
            )
            longest.append({"ms": round(1e3 * (t1 - t0), 3), "held_by": by})
        per[tid] = {
            "lock_takes": len(ws),
            "lock_wait_sum_ms": round(1e3 * sum(b - a for a, b in ws), 3),
            "lock_wait_max_ms": longest[0]["ms"] if longest else 0.0,
            "lock_waits_over_1ms": sum(b - a > 1e-3 for a, b in ws),
            "lock_longest_waits": longest,
        }
    for tid, a, b, w in holds:
        if w:
            p = per.setdefault(tid, {})
            p["write_holds"] = p.get("write_holds", 0) + 1
            p["write_hold_max_ms"] = max(p.get("write_hold_max_ms", 0.0), round(1e3 * (b - a), 3))
    return per


def main() -> int:
    if len(sys.argv) < 4 or sys.argv[2] != "--":
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    cmd = sys.argv[3:]
    seconds = float(cmd[cmd.index("--seconds") + 1]) if "--seconds" in cmd else 600.0
    with (out / "soak.json").open("wb") as so, (out / "soak.err").open("wb") as se:
        soak = subprocess.Popen(cmd, stdout=so, stderr=se)
        daemon = sampler = None
        deadline = time.monotonic() + 300
        while soak.poll() is None and time.monotonic() < deadline:
            daemon = daemon or _descendant(soak.pid, "tvsd.daemon.main")
            sampler = _descendant(soak.pid, "tvsd.sim.proc_watch")
            if daemon and sampler:
                break
            time.sleep(0.5)
        if not (daemon and sampler):
            print("soak_mmlock: the daemon or its load never appeared", file=sys.stderr)
            soak.wait()
            return 1
        names = _names(daemon)
        mm = _mm_of(daemon, out / "mm0.data")
        dur = str(max(seconds - 15.0, 5.0))
        stat = subprocess.Popen(
            ["perf", "stat", "--per-thread", "-x,", "-o", str(out / "stat.csv"), "-e", ",".join(EVENTS),
             "-p", str(daemon), "--", "sleep", dur],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        # the whole machine's events on the daemon's mm (its threads and any other task), else its own
        where = ["-a", "--filter", f"mm == {mm}"] if mm else ["-p", str(daemon)]
        rec = subprocess.Popen(
            ["perf", "record", "-q", "-o", str(out / "mmlock.data"), "-e", LOCK_EVENTS, *where,
             "--", "sleep", dur],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        grow = subprocess.Popen(
            ["perf", "record", "-q", "-o", str(out / "grow.data"), "-e", "syscalls:sys_enter_mprotect",
             "-p", str(daemon), "--", "sleep", dur],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        reader = next((t for t, n in names.items() if n == "imu-reader"), None)
        faults = subprocess.Popen(
            ["perf", "record", "-q", "-c", "1", "-d", "-o", str(out / "faults.data"), "-e", "minor-faults",
             "-t", str(reader), "--", "sleep", dur],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        ) if reader else None  # fmt: skip
        maps = ""
        while stat.poll() is None:  # the daemon's mappings, latest before the trace ends
            with contextlib.suppress(OSError):
                maps = Path(f"/proc/{daemon}/maps").read_text()
            time.sleep(2.0)
        rec.wait()
        grow.wait()
        if faults is not None:
            faults.wait()
        names.update(
            {k: v for k, v in _names(daemon).items() if k not in names}
            if Path(f"/proc/{daemon}").exists()
            else {}
        )
        rc = soak.wait()
    calls = _stat(out / "stat.csv")
    if reader and (out / "faults.data").exists():
        calls.setdefault(reader, {})["fault_where"] = _fault_where(out / "faults.data", maps)
    for tid, kib in _grown(out / "grow.data").items():
        calls.setdefault(tid, {})["mprotect_kib"] = kib
    locks = _analyse(_locks(out / "mmlock.data", names, daemon), names)
    threads = {}
    for tid in sorted(set(calls) | set(locks)):
        row = {**calls.get(tid, {}), **locks.get(tid, {})}
        if any(v for k, v in row.items() if k != "lock_longest_waits"):
            threads[f"{names.get(tid, '?')}[{tid}]"] = row
    (out / "mm.json").write_text(
        json.dumps({"daemon": daemon, "seconds_traced": float(dur), "threads": threads}, indent=1)
    )
    for name, row in threads.items():
        brief = {k: v for k, v in row.items() if k != "lock_longest_waits"}
        print(name, json.dumps(brief))
    return rc


if __name__ == "__main__":
    sys.exit(main())
