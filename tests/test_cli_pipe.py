"""tvsctl when stdout's reader goes away (`tvsctl status | head -3`, found by branch newuser).

A real `| head` races the writer; here the reader leaves at a chosen point, so each ordering is
deterministic: before tvsctl's first write (every write fails: quiet, EXIT_PIPE), or after the
command returned and before the interpreter's last flush (the stranger's "Exception ignored …
BrokenPipeError": the command's last lines still sat in stdout's buffer).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tvsd.daemon.rpc import ThreadedRpcServer
from tvsd.errors import EXIT_PIPE

# The stranger's status: ten 600-character fault lines (6 kB: below stdout's 8 kB buffer, so the
# only write happens at the flush) and a long one (60 kB: many writes inside the command).
LONG = "x" * 600


def _status(n_faults: int) -> dict[str, object]:
    faults = [{"cause": "mcu_watchdog", "message": f"{k} {LONG}"} for k in range(n_faults)]
    return {"state": "fault", "rps": 0.0, "faults": faults}


# A user's stdout into a pipe is block-buffered; PYTHONUNBUFFERED (set in some shells and CI)
# would hide the buffered tail this is about.
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}


@contextmanager
def _serving(n_faults: int) -> Iterator[Path]:
    """A stand-in daemon on a real socket answering `status` with `n_faults` long faults."""
    status = _status(n_faults)

    async def answer() -> dict[str, object]:
        return status

    with (
        tempfile.TemporaryDirectory(prefix="tvs") as tmp,
        ThreadedRpcServer(Path(tmp) / "s.sock", {"status": answer}) as server,
    ):
        yield server.path


@pytest.fixture(params=[10, 100])
def stand_in(request: pytest.FixtureRequest) -> Iterator[Path]:
    with _serving(request.param) as path:
        yield path


def _tvsctl_reader_gone(*argv: str) -> subprocess.CompletedProcess[str]:
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first write
    try:
        return subprocess.run(
            [sys.executable, "-m", "tvsd.cli.main", *argv],
            stdout=write_end,
            stderr=subprocess.PIPE,
            text=True,
            timeout=120,
            check=False,
            env=ENV,
        )
    finally:
        os.close(write_end)


@pytest.mark.parametrize("json_flag", [(), ("--json",)])
def test_daemon_command_into_a_closed_pipe_is_quiet(stand_in: Path, json_flag: tuple[str, ...]) -> None:
    done = _tvsctl_reader_gone("status", "--socket", str(stand_in), *json_flag)
    assert done.stderr == ""
    assert done.returncode == EXIT_PIPE


def test_reader_gone_after_the_command_before_exit_is_quiet() -> None:
    """The child holds the pipe's only reader and closes it when main() has returned, before the
    interpreter's exit: what `head` does when it leaves between tvsctl's last write and its exit.
    Before: the buffered tail failed in that last flush ("Exception ignored", exit 120)."""
    read_end, write_end = os.pipe()  # 6 kB of output: the pipe (64 kB) holds it all, nobody reads
    with _serving(10) as sock:
        child = _status_then_close_reader(sock, read_end, write_end)
        _, err = child.communicate("go\n", timeout=120)
    assert err == ""
    assert child.returncode == 0  # everything reached the pipe before the reader left


def _status_then_close_reader(sock: Path, read_end: int, write_end: int) -> subprocess.Popen[str]:
    code = (
        "import os, sys; from tvsd.cli.main import main; "
        f"status = main(['status', '--socket', {str(sock)!r}]); "
        f"sys.stdin.readline(); os.close({read_end}); sys.exit(status)"
    )
    child = subprocess.Popen(
        [sys.executable, "-c", code],
        stdin=subprocess.PIPE,
        stdout=write_end,
        stderr=subprocess.PIPE,
        pass_fds=(read_end,),
        text=True,
        env=ENV,
    )
    os.close(read_end)  # the child's copy is now the only reader
    os.close(write_end)
    return child


def test_help_into_a_closed_pipe_is_quiet() -> None:
    # argparse prints --help and leaves by SystemExit, outside the command's try
    done = _tvsctl_reader_gone("--help")
    assert done.stderr == ""
    assert done.returncode == EXIT_PIPE


def test_pipe_open_is_unchanged(stand_in: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "tvsd.cli.main", "status", "--socket", str(stand_in)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env=ENV,
    )
    assert (done.returncode, done.stderr) == (0, "")
    assert done.stdout.count(LONG) >= 10
