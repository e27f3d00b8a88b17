"""What the emulated boards share (tvsd/sim/qemu_mcu.py, tvsd/sim/simavr_mcu.py): build an image
with the firmware's Makefile, start the emulator in its own session and killed with its parent
(PR_SET_PDEATHSIG: a test that dies leaves no emulator behind), wait for what it prints on
starting, stop it.
"""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Self

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
_PR_SET_PDEATHSIG = 1
_prctl = ctypes.CDLL(None, use_errno=True).prctl  # resolved here: the child after fork only calls it


def _die_with_parent() -> None:
    """In the child: killed when the thread that started it ends (start it from a long-lived one)."""
    _prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)


def have_firmware_tree() -> bool:
    """A source checkout's firmware/ is beside the package (an installed wheel has none: it carries
    the host core only, tvsd/sim/_vmcu*.so)."""
    return (FIRMWARE_DIR / "Makefile").is_file()


def make(target: str, out: Path, error: type[Exception]) -> Path:
    """`make -C firmware <target>`; `out`, or one clear `error` on one line."""
    if not have_firmware_tree():
        raise error(
            f"the {target} firmware image is built from a source checkout's firmware/ (the installed "
            f"package carries only the host core): run make -C firmware {target} in a tvsd checkout"
        )
    proc = subprocess.run(
        ["make", "-C", str(FIRMWARE_DIR), target], capture_output=True, text=True, check=False
    )
    if proc.returncode != 0 or not out.exists():
        lines = proc.stderr.strip().splitlines() or ["no output"]
        # the compiler's first error says why; make's own last line ("*** [...] Error 1") does not
        said = next((ln for ln in lines if "error" in ln.lower()), lines[-1]).strip()[:300]
        raise error(
            f"building {out} failed (make -C {FIRMWARE_DIR} {target}, status {proc.returncode}): {said}"
        )
    return out


def spawn(cmd: list[str], log_path: str) -> subprocess.Popen[bytes]:
    """Start `cmd` with stdout and stderr to `log_path` (a file: a pipe nobody reads fills)."""
    with open(log_path, "wb") as log:
        return subprocess.Popen(
            cmd,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
            preexec_fn=_die_with_parent,  # prctl must run in the child
            start_new_session=True,
        )


def wait_started(
    proc: subprocess.Popen[bytes], log_path: str, ready: Callable[[bytes], bool], timeout_s: float
) -> bytes | None:
    """Poll the log until `ready(log)`; the log, or None when the process ended or time ran out."""
    deadline = time.monotonic() + timeout_s
    while True:
        with open(log_path, "rb") as log:
            seen = log.read()
        if ready(seen):
            return seen
        left = deadline - time.monotonic()
        if left <= 0 or proc.poll() is not None:
            return None
        time.sleep(min(left, 0.02))


def log_tail(log_path: str) -> str:
    with open(log_path, "rb") as log:
        return log.read().decode(errors="replace")[-500:]


def stop(proc: subprocess.Popen[bytes] | None) -> None:
    """SIGTERM, then SIGKILL after 5 s; reaped either way."""
    if proc is not None and proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


class EmulatedBoard:
    """An emulator process with a temporary folder for its log; subclasses start it."""

    def __init__(self, elf: Path, name: str) -> None:
        self.elf = elf
        self.port = ""
        self._proc: subprocess.Popen[bytes] | None = None
        self._dir = tempfile.TemporaryDirectory(prefix=f"tvsd-{name}-")
        self._log_path = os.path.join(self._dir.name, f"{name}.log")

    def start(self) -> str:
        raise NotImplementedError

    def close(self) -> None:
        proc, self._proc = self._proc, None
        stop(proc)
        self._dir.cleanup()

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def __enter__(self) -> Self:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
