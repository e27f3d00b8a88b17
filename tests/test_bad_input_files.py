"""Data files as other tools write them (tvsctl analyze's reader, tvsd/recording/csvfile.py): a
spreadsheet's UTF-8 byte-order mark is read, not refused; a file with other separators, a
directory or an unreadable file is one line naming the cause and the fix, exit 2."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from tvsd.cli.main import main
from tvsd.errors import DataFileError
from tvsd.recording import csvfile

T = np.arange(3000) / 1000
U = np.where((T % 1) < 0.5, 5.0, -5.0)
W = np.cumsum(U) / 1000


def _text(sep: str = ",", newline: str = "\n") -> str:
    lines = ["# tvs-recording: 1", "# sample_rate_hz: 1000", sep.join(("t", "u", "omega"))]
    lines += [sep.join((f"{a:.4f}", repr(float(b)), repr(float(c)))) for a, b, c in zip(T, U, W, strict=True)]
    return newline.join(lines) + newline


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_a_byte_order_mark_is_read(tmp_path: Path, newline: str) -> None:
    """Excel's "CSV UTF-8" starts with U+FEFF: it was refused as "expected '# tvs-recording: 1' as
    the first line, got '\\ufeff# tvs-recording: 1'"."""
    path = tmp_path / "bom.csv"
    path.write_bytes(b"\xef\xbb\xbf" + _text(newline=newline).encode())
    rec = csvfile.read(path)
    assert len(rec.t) == len(T) and np.allclose(rec.omega, W)


@pytest.mark.parametrize("sep", [";", "\t"])
def test_other_separators_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str], sep: str) -> None:
    path = tmp_path / "semi.csv"
    path.write_text(_text(sep))
    assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"separated by {sep!r}" in err and "uses ','" in err and err.count("\n") == 1, err


def test_a_directory_says_how_to_get_a_csv(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["analyze", str(tmp_path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "is a directory" in err and "tvsctl export" in err and err.count("\n") == 1, err


def test_an_unreadable_file_says_permission(tmp_path: Path) -> None:
    path = tmp_path / "r.csv"
    path.write_text(_text())
    path.chmod(0)
    if os.access(path, os.R_OK):
        pytest.skip("this user reads any file (root)")
    with pytest.raises(DataFileError, match="permission denied; check the file's mode"):
        csvfile.read(path)


def _as_nobody(*argv: str) -> subprocess.CompletedProcess[str]:
    setpriv = shutil.which("setpriv")
    if os.geteuid() != 0 or setpriv is None:
        pytest.skip("needs root and setpriv to run a process as another user")
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["HOME"] = "/nonexistent"
    cmd = [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups", sys.executable, "-m", "tvsd.cli.main"]
    return subprocess.run([*cmd, *argv], cwd="/", env=env, capture_output=True, text=True, timeout=120)


def test_export_of_a_recording_this_user_may_not_read_says_permission() -> None:
    """The daemon makes recordings 0750: another user's export said "not a tvsd recording (no
    seg-*.tvsrec segment files in it)", and one under an unsearchable directory was an internal
    error (exit 70, PermissionError)."""
    with tempfile.TemporaryDirectory() as top:
        os.chmod(top, 0o755)
        rec = Path(top) / "rec-20261126-120000"
        rec.mkdir(mode=0o750)
        (rec / "seg-0000.tvsrec").write_bytes(b"")
        hidden = Path(top) / "private"
        hidden.mkdir(mode=0o700)
        for path, needle in ((rec, "permission denied (the daemon makes them 0750)"),
                             (hidden / "rec-x", "permission denied on a directory above it")):  # fmt: skip
            run = _as_nobody("export", str(path), "--csv", str(Path(top) / "out.csv"))
            assert run.returncode == 2 and needle in run.stderr, run.stderr
            assert run.stderr.count("\n") == 1, run.stderr


@pytest.mark.parametrize(
    "scale_u,scale_w,needle",
    [(1e-300, 1e-300, "varies by only"), (1.0, 1e-300, "the speed never changes")],
)
def test_signals_too_small_to_be_measurements_are_bad_input(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], scale_u: float, scale_w: float, needle: str
) -> None:
    """u and ω of ~1e-300 passed the 'constant' checks (their span is not 0), then the fit's sums of
    squares underflowed: two numpy RuntimeWarnings and a ZeroDivisionError, exit 70."""
    import warnings

    lines = ["# tvs-recording: 1", "# sample_rate_hz: 1000", "t,u,omega"]
    speed = 100 + np.cumsum(U - 0.0) / 1000
    lines += [
        f"{a:.4f},{float(b) * scale_u!r},{float(c) * scale_w!r}" for a, b, c in zip(T, U, speed, strict=True)
    ]
    path = tmp_path / "tiny.csv"
    path.write_text("\n".join(lines) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err


def test_a_device_or_a_pipe_is_not_read(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`tvsctl analyze /dev/zero` read until MemoryError (exit 70); a FIFO blocked for ever."""
    fifo = tmp_path / "f.csv"
    os.mkfifo(fifo)
    for path in (Path("/dev/zero"), fifo):
        assert main(["analyze", str(path), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "not a regular file" in err and err.count("\n") == 1, err
