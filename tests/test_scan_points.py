"""Point outputs: CSV round trip, PLY layout, stream records — one field list for all three."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tvsd.errors import UsageError
from tvsd.scan.points import FIELDS, FLAG_VIBRATION, PointCloud, read_csv, write, write_ply


def cloud(n: int = 5) -> PointCloud:
    rng = np.random.default_rng(0)
    cols = {f: rng.normal(size=n) for f in FIELDS}
    cols["t"] = 1000.0 + np.arange(n) * 0.05  # long runs: the time keeps its µs
    cols["flags"] = np.arange(n, dtype=np.int64) % 8
    return PointCloud(**cols)


def test_csv_round_trip(tmp_path):
    c = cloud()
    write(c, tmp_path / "p.csv")
    back = read_csv(tmp_path / "p.csv")
    for f in FIELDS:
        # 9 significant digits (t: 9 decimals) is what the writer promises.
        np.testing.assert_allclose(getattr(back, f), getattr(c, f), rtol=1e-8, atol=1e-9, err_msg=f)


def test_ply_puts_xyz_first_and_keeps_flags_integer(tmp_path):
    write_ply(cloud(3), tmp_path / "p.ply")
    lines = (tmp_path / "p.ply").read_text().splitlines()
    props = [ln.split()[-1] for ln in lines if ln.startswith("property")]
    assert props[:3] == ["x", "y", "z"] and sorted(props) == sorted(FIELDS)
    assert "property int flags" in lines
    assert [int(ln.split()[-1]) for ln in lines[lines.index("end_header") + 1 :]] == [0, 1, 2]


def test_points_carry_the_same_fields_and_their_json_adds_t_mono():
    points = list(cloud(4).points())
    assert len(points) == 4 and all(tuple(p.to_json())[: len(FIELDS)] == FIELDS for p in points)
    assert isinstance(points[1].flags, int) and points[1].flags & FLAG_VIBRATION
    assert points[1].to_json()["x"] == points[1].x and math.isnan(points[1].to_json()["t_mono"])


def test_bad_paths_and_files_are_one_line_errors(tmp_path):
    with pytest.raises(UsageError, match=r"\.csv or \.ply"):
        write(cloud(), tmp_path / "p.txt")
    with pytest.raises(UsageError, match="cannot write"):
        write(cloud(), tmp_path / "missing" / "p.csv")
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n")
    with pytest.raises(UsageError, match="not a tvs-points CSV"):
        read_csv(tmp_path / "bad.csv")
