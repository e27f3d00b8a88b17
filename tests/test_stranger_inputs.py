"""Bad input a stranger tried on the installed wheel (docs/measurements/newuser.md): each was a
traceback or "internal error" (exit 70), or a silent choice, before; now one line, exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.io import savemat

from tvsd.cli.main import main

T = np.arange(3000) / 1000


def _emps(path: Path, **over: object) -> Path:
    data: dict[str, object] = {"t": T, "qm": np.sin(T), "vir": np.cos(3 * T), "gtau": 35.15}
    data.update(over)
    savemat(str(path), data)
    return path


@pytest.mark.parametrize(
    ("over", "said"),
    [
        ({"t": "abc"}, "variable t holds"),  # was ValueError: could not convert string to float
        ({"vir": {"a": 1}}, "variable vir holds"),  # a struct: ValueError, setting an array element
        ({"vir": np.array([[1, 2], [3]], dtype=object)}, "variable vir holds"),  # a cell
        ({"qm": np.sin(T) + 1j}, "variable qm holds complex"),  # was a ComplexWarning, then a fit
        ({"gtau": np.array([])}, "gtau must be one positive number"),  # was IndexError
        ({"gtau": np.nan}, "gtau must be one positive number"),  # was a fit with a NaN gain
        ({"gtau": -3.0}, "gtau must be one positive number"),
    ],
)
def test_a_mat_file_with_wrong_variables_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], over: dict, said: str
) -> None:
    path = _emps(tmp_path / "bad.mat", **over)
    assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert said in err and err.count("\n") == 1, err


def test_an_empty_mat_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "empty.mat"
    path.write_bytes(b"")  # was exit 70: MatReadError "Mat file appears to be truncated"
    assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "not a readable MATLAB .mat file" in err and err.count("\n") == 1, err


def _csv(path: Path, meta: list[str]) -> Path:
    u = np.where((T % 1) < 0.5, 5.0, -5.0)
    w = np.cumsum(u) / 1000
    lines = ["# tvs-recording: 1", "# sample_rate_hz: 1000", *meta, "t,u,omega"]
    lines += [f"{a:.4f},{b!r},{c!r}" for a, b, c in zip(T, u, w, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_metadata_key_given_twice_with_two_values_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`# u_unit: V` then `# u_unit: A`: the last one won silently, so the doctor read volts as amps."""
    path = _csv(tmp_path / "twice.csv", ["# u_unit: V", "# u_unit: A"])
    assert main(["analyze", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "row 4: 'u_unit' is given again (first at row 3)" in err and err.count("\n") == 1, err


@pytest.mark.parametrize("where", ["missing/rep", "afile"])
def test_a_report_folder_that_cannot_be_made_is_refused_before_the_analysis(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    """`--report /nonexistent/rep` made every missing parent (as root) after the analysis; a file
    in the way was found only after it. Both are now refused first: the CSV here is not even read
    (it does not exist), so the answer names the report, not the file."""
    (tmp_path / "afile").write_text("")
    out = tmp_path / where
    assert main(["analyze", str(tmp_path / "nope.csv"), "--quiet", "--report", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"tvsctl: --report {out}:") and err.count("\n") == 1, err
    assert not (tmp_path / "missing").exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="drops root to an unprivileged uid")
def test_realtime_refused_says_what_is_missing() -> None:
    """`tvsd --realtime` as an unprivileged user said only "event loop SCHED_FIFO refused:
    Operation not permitted": not what to grant. The refusal, as nobody (uid 65534)."""
    code = "import os; from tvsd.daemon.main import _io_side_realtime; os.setuid(65534); _io_side_realtime()"
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    line = proc.stderr.strip()
    assert "refused" in line and "CAP_SYS_NICE" in line and "rtprio" in line and "\n" not in line, line


@pytest.mark.parametrize("in_the_way", ["missing", "file"])
def test_a_refused_socket_folder_leaves_no_data_dir_behind(tmp_path: Path, in_the_way: str) -> None:
    """tvsd made --data-dir, then found the socket's folder unusable: a failed start left an
    empty data dir behind. Now every folder is judged before any is made (fails before the fix)."""
    from tvsd.daemon.main import main as tvsd_main

    if in_the_way == "file":
        (tmp_path / "run").write_text("")  # a file where the socket's folder should be
        sock = tmp_path / "run" / "x.sock"
    else:
        sock = tmp_path / "nonexistent" / "dir" / "x.sock"
    assert tvsd_main(["--sil", "--socket", str(sock), "--data-dir", str(tmp_path / "data")]) == 2
    assert not (tmp_path / "data").exists()


@pytest.mark.skipif(os.geteuid() != 0, reason="drops root to an unprivileged uid")
def test_an_unwritable_socket_folder_is_refused_before_the_data_dir_is_made() -> None:
    """The stranger's start: `tvsd --sil --data-dir ~/data` with the default socket /run/tvsd, whose
    parent only root may write. As nobody (uid 65534), in a world-writable folder."""
    import tempfile

    top = Path(tempfile.mkdtemp(prefix="tvs-nobody-"))
    try:
        top.chmod(0o777)
        (top / "root-only").mkdir(mode=0o755)
        code = (
            # what main() imports, imported as root first (the venv may not be readable by nobody)
            "import os, sys, dataclasses, tvsd.config, tvsd.control.conditions, tvsd.hw.imu_calibration; "
            "from tvsd.daemon.main import main; os.setuid(65534); "
            f"sys.exit(main(['--sil', '--data-dir', '{top}/data', '--socket', '{top}/root-only/run/s.sock']))"
        )
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.strip().splitlines()[-1].startswith("tvsd: --socket: cannot create"), proc.stderr
        assert not (top / "data").exists()
    finally:
        for sub in ("root-only", "data"):
            if (top / sub).is_dir():
                (top / sub).rmdir()
        top.rmdir()
