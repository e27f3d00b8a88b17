"""`tvsctl sim scan` through an argparse harness (the lead wires `register` into tvsctl sim)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from tvsd.cli import sim_scan
from tvsd.errors import UsageError
from tvsd.scan.points import FIELDS, FLAG_COMPENSATED, read_csv

SMALL = ["--rps", "20", "--sigma-v", "0.0838,0.8069", "--seconds", "4"]


def parse(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="tvsctl sim")
    sim_scan.register(parser.add_subparsers())
    return parser.parse_args(["scan", *argv])


def run(capsys, *argv: str) -> tuple[int, str]:
    args = parse(*argv)
    code = args.func(args)
    return code, capsys.readouterr().out


def test_json_has_the_contract_and_the_outputs_are_written(capsys, tmp_path):
    pts, png = tmp_path / "points.csv", tmp_path / "scan.png"
    code, out = run(capsys, *SMALL, "--json", "--points", str(pts), "--plot", str(png))
    assert code == 0
    res = json.loads(out)
    assert len(res["cases"]) == 2 * 9 * 2
    for case in res["cases"]:
        assert set(case) >= {
            "gamma_deg",
            "phi_deg",
            "rps",
            "sigma_v",
            "compensated",
            "err_std_mm",
            "bias_mm",
            "reported_sigma_mm",
            "coverage_2sigma",
        }
        assert len(case["err_std_mm"]) == len(case["bias_mm"]) == len(case["reported_sigma_mm"]) == 3
    assert res["compensation_gain_x"] >= 2.0
    assert "swapped" in res["table4"]["note"] and res["geometry"]["range_m"] == 2.0
    cloud = read_csv(pts)
    assert len(cloud) > 9 * 2 * 70  # 4 s at 20 rev/s: ~78 centred points per target
    assert np.all(cloud.flags & FLAG_COMPENSATED)  # the written points are the compensated ones
    assert np.all(cloud.sigma_x > 0) and np.all(np.isfinite(cloud.vibration))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_human_output_has_the_table_and_the_table4_summary(capsys):
    code, out = run(capsys, *SMALL, "--effect", "none")
    assert code == 0
    assert "err std x/y/z mm" in out and "paper Table 4" in out and "compensation gain" in out
    assert "effects: none" in out


def test_ply_output(capsys, tmp_path):
    ply = tmp_path / "points.ply"
    run(capsys, "--rps", "25", "--sigma-v", "0.3381", "--seconds", "2", "--points", str(ply))
    lines = ply.read_text().splitlines()
    n = int(next(line for line in lines if line.startswith("element vertex")).split()[-1])
    body = lines[lines.index("end_header") + 1 :]
    assert n == len(body) > 0 and len(body[0].split()) == len(FIELDS)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--seconds", "0.5"], "--seconds 0.5 is outside"),
        (["--rps", "50"], "--rps"),
        (["--sigma-v", "9"], "stop the aperture"),
        (["--range-m", "0.1"], "--range-m 0.1 is outside"),
        (["--points", "x.txt"], "ending in .csv or .ply"),
        (["--effect", "wobble:x=1"], "wobble"),
    ],
)
def test_bad_input_is_one_clear_line(argv, message):
    args = parse(*argv)
    with pytest.raises(UsageError, match=message) as exc:
        args.func(args)
    assert "\n" not in str(exc.value)


def test_malformed_lists_are_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit) as exc:
        parse("--rps", "fast")
    assert exc.value.code == 2
    assert "not a comma-separated list" in capsys.readouterr().err
