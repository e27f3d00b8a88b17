"""A benchmark's Python child, measured: wall, CPU, peak resident memory, and what it allocated.

Two memory figures, for two questions. Peak RSS (VmHWM) is what a user sees in `top`: every page
the child had resident, its shared libraries' pages among them. Those depend on the page cache, not
on the code: `import numba` raised the RSS by 62 MiB in one clone's venv and by 111 MiB in
another's (same wheels, same interpreter; docs/measurements/session6.md), so the same analysis
peaked at 242 MiB in one and 293 in the other. Anonymous memory (RssAnon: the heap, numpy's arrays,
the JIT's code) is what the code allocates, the same in both (138 MiB; memflake.md). The child
reports its anonymous memory once a prelude (imports, kernels) has run, and the parent samples it
from then on: the rise above that base is what the measured code itself allocated.
"""

from __future__ import annotations

import math
import os
import subprocess
import tempfile
import time
from typing import NamedTuple

SAMPLE_S = 0.001  # the parent reads the child's RssAnon this often: the doctor's peak holds for ms

# The child reports on a pipe: `base KIB` (its RssAnon after the prelude) and, as it exits,
# `hwm KIB` (the peak of its own memory map). wait4's ru_maxrss will not do: exec keeps the larger
# of the old and new maps' peaks, and the old map is the parent's (fork and vfork alike), so under
# pytest a 10 MiB child read 593 MiB. For the same reason the parent samples /proc/PID only after
# `base`: before the exec, PID's map is the parent's.
_WRAPPER = """
import atexit, os, runpy, sys
def _kib(key):
    with open('/proc/self/status') as f:
        return next((ln.split()[1] for ln in f if ln.startswith(key + ':')), 'nan')
fd, prelude, flag, what, *rest = int(sys.argv[1]), *sys.argv[2:]
atexit.register(lambda: os.write(fd, f'hwm {_kib("VmHWM")}\\n'.encode()))
if prelude:
    exec(compile(prelude, '<prelude>', 'exec'), {'__name__': '__prelude__'})
os.write(fd, f'base {_kib("RssAnon")}\\n'.encode())
sys.argv = [what if flag == '-m' else '-c', *rest]
if flag == '-m':
    runpy.run_module(what, run_name='__main__', alter_sys=True)
else:
    exec(compile(what, '<string>', 'exec'), {'__name__': '__main__'})
"""


class Child(NamedTuple):
    wall_s: float
    cpu_s: float  # user + system, from the child's own rusage (wait4)
    peak_rss_mib: float  # VmHWM: the shared libraries' resident pages included
    peak_anon_mib: float  # the largest RssAnon sampled after the prelude
    base_anon_mib: float  # RssAnon when the prelude had run

    @property
    def own_mib(self) -> float:
        """Anonymous memory the measured code took above the prelude's: what it allocated (NaN
        when the child did not report its base)."""
        own = self.peak_anon_mib - self.base_anon_mib
        return max(own, 0.0) if math.isfinite(own) else math.nan


def _anon_kib(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next((int(ln.split()[1]) for ln in f if ln.startswith("RssAnon:")), 0)
    except (OSError, ValueError):  # gone, or a zombie (no memory lines)
        return 0


def run_child(cmd: list[str], env: dict[str, str], prelude: str = "") -> Child:
    """Measure one Python child (`python -m M …` or `python -c S …`), `prelude` (Python source)
    run in it first and its memory taken as the base."""
    if cmd[1] not in ("-m", "-c"):
        raise ValueError(f"bench children are `python -m` or `python -c`, got {cmd[:2]}")
    pipe_r, pipe_w = os.pipe()
    with tempfile.TemporaryFile() as err:  # a file, not a pipe: nobody reads it while we sample
        t0 = time.perf_counter()
        try:
            proc = subprocess.Popen(
                [cmd[0], "-c", _WRAPPER, str(pipe_w), prelude, *cmd[1:]],
                env=env,
                stdout=subprocess.DEVNULL,
                stderr=err,
                pass_fds=(pipe_w,),
            )
        finally:
            os.close(pipe_w)
        os.set_blocking(pipe_r, False)
        said, peak_kib = b"", 0
        while True:
            pid, status, ru = os.wait4(proc.pid, os.WNOHANG)
            said += _read_all(pipe_r)
            if pid:
                break
            if b"base " in said:
                peak_kib = max(peak_kib, _anon_kib(proc.pid))
            time.sleep(SAMPLE_S)
        wall = time.perf_counter() - t0
        os.close(pipe_r)
        err.seek(0)
        message = err.read().decode(errors="replace")
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd[2:5])} … exited {proc.returncode}: {message.strip()[-300:]}")
    base_kib, hwm_kib = _figures(said)
    return Child(
        wall,
        ru.ru_utime + ru.ru_stime,
        hwm_kib / 1024.0,
        max(peak_kib, base_kib) / 1024.0 if math.isfinite(base_kib) else math.nan,
        base_kib / 1024.0,
    )


def _figures(said: bytes) -> tuple[float, float]:
    """(base, hwm) KiB as the child reported them; NaN for one it did not report (its measured
    code left by os._exit, which skips atexit) or could not read (a kernel without RssAnon,
    before 4.5): unknown, not 0 — a 0 read as a measured figure (`own_mib` 0)."""
    figures = dict(line.split() for line in said.decode().splitlines() if line.count(" ") == 1)
    return float(figures.get("base", "nan")), float(figures.get("hwm", "nan"))


def _read_all(fd: int) -> bytes:
    out = b""
    while True:
        try:
            chunk = os.read(fd, 4096)
        except BlockingIOError:
            return out
        if not chunk:
            return out
        out += chunk
