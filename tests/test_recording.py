"""The recording CSV contract: round trip, and one clear line for every kind of bad file."""

from __future__ import annotations

import numpy as np
import pytest

from tvsd.errors import DataFileError
from tvsd.recording.csvfile import read, write

GOOD = "# tvs-recording: 1\n# sample_rate_hz: 1000\n# rps_setpoint: 20\nt,u,omega,phi\n"


def _rows(n: int = 5) -> str:
    return "".join(f"{k / 1000:.3f},1.0,{2.0 + k},{0.01 * k}\n" for k in range(n))


def test_round_trip_keeps_columns_and_metadata(tmp_path):
    t = np.arange(100) / 1000
    path = tmp_path / "r.csv"
    write(path, t, np.sin(t), np.cos(t), t * 2, 1000, {"gamma_deg": 15}, {"i": t * 3})
    rec = read(path)
    assert np.allclose(rec.omega, np.cos(t)) and np.allclose(rec.extra["i"], t * 3)
    assert rec.meta["gamma_deg"] == "15" and rec.phi_measured


def test_phi_is_integrated_from_omega_when_absent(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text(
        "# tvs-recording: 1\n# sample_rate_hz: 100\nt,u,omega\n"
        + "".join(f"{k / 100},0,2.0\n" for k in range(11))
    )
    rec = read(path)
    assert not rec.phi_measured and rec.phi[-1] == pytest.approx(0.2)


@pytest.mark.parametrize(
    "text,row,needle",
    [
        ("t,u,omega\n0,0,0\n", 1, "expected '# tvs-recording: 1'"),
        ("# tvs-recording: 1\nt,u,omega\n0,0,0\n", 2, "missing '# sample_rate_hz"),
        ("# tvs-recording: 1\n# sample_rate_hz: fast\nt,u\n", 2, "positive number"),
        (
            "# tvs-recording: 1\n# sample_rate_hz: 1000\nt,u,phi\n0,0,0\n0.001,0,0\n",
            3,
            "missing column(s) omega",
        ),
        (GOOD + "0,1,2,3\n0.001,1,nan,3\n", 6, "NaN"),
        (GOOD + "0,1,2,3\n0.001,1,2\n", 6, "3 values in '0.001,1,2', the header t,u,omega,phi has 4"),
        (GOOD + "0,1,2,3\n0.001,1,x,3\n", 6, "not a number"),
        (GOOD + "0,1,2,3\n0.001,1,2,3\n0.0005,1,2,3\n", 7, "does not increase"),
        (GOOD + "0,1,2,3\n0.001,1,2,3\n0.003,1,2,3\n", 7, "differs from 1/sample_rate_hz"),
        (GOOD + "0,1,2,3\n", 5, "at least 2"),
    ],
)
def test_bad_files_name_file_row_and_problem(tmp_path, text, row, needle):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(DataFileError) as info:
        read(path)
    message = str(info.value)
    assert message.startswith(f"{path}: row {row}: ") and needle in message


def test_missing_and_binary_files(tmp_path):
    with pytest.raises(DataFileError, match="no such file"):
        read(tmp_path / "none.csv")
    binary = tmp_path / "b.csv"
    binary.write_bytes(b"\xff\xfe\x00\x01")
    with pytest.raises(DataFileError, match="binary data, not a recording CSV"):
        read(binary)


def test_whole_body_parse_equals_row_by_row_and_bad_rows_still_named(tmp_path):
    """The reader parses the body in one pass and falls back to row by row only to name a bad
    row: the values must be exactly float() of each field either way (same function), and a bad
    row far into a good file is still the one named."""
    from tvsd.recording import csvfile

    fields = ["0.001", " 2.5", "+3", "-1e-3", "4.000000001", "1_0", "7e14", "-0.0"]
    body = [",".join(fields[(k + j) % len(fields)] for j in range(4)) for k in range(64)]
    fast = csvfile._parse_fast(body, 4)
    slow = csvfile._parse_slow(body, 0, ["t", "u", "omega", "phi"], lambda row, msg: DataFileError(msg), True)
    assert fast is not None and np.array_equal(fast, slow)
    assert np.array_equal(fast[:, 0], [float(fields[k % len(fields)]) for k in range(64)])
    rows = "".join(f"{k / 1000:.3f},1.0,2.0,0.0\n" for k in range(500)).splitlines(keepends=True)
    rows[400] = "0.400,1.0,2.0,1e309\n"
    path = tmp_path / "late.csv"
    path.write_text(GOOD + "".join(rows))
    with pytest.raises(DataFileError, match=r"row 405: NaN or infinite"):
        read(path)
