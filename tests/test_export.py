"""`tvsctl export` of daemon recordings with gaps, repeats, the reference and faults (issue 13 item 4).

Before: export refused the whole file over one missing 1 ms sample (5 of 9 recordings made under
load), wrote neither the controller's reference nor the fault marks, and said nothing of u's unit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tvsd.cli import main as cli
from tvsd.daemon.session_recording import PWM_FIELDS, REFERENCE_FIELDS
from tvsd.recording.csvfile import read as read_csv
from tvsd.recording.format import LOOP_FIELDS
from tvsd.recording.writer import Recorder

CONFIG = "plant:\n  name: bench\ncontrol:\n  rate_hz: 10000\n"
T0 = 100.0  # the loop's clock (s since the control thread started) at the first bin


def _rows(k: np.ndarray) -> dict[str, np.ndarray]:
    return {"t": T0 + k / 1000, "u": np.sin(k / 50), "omega": 150 + np.cos(k / 70), "phi": k * 0.15}


def _reference(k: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "t": T0 + k / 1000,
        "phi_ref": k * 0.16,
        "omega_ref": np.full(len(k), 157.0),
        "u_ff": np.full(len(k), 5.9),
    }


def _record(path: Path, parts: list[np.ndarray], faults: list[tuple[float, str, str]] = ()) -> None:
    with Recorder(path, CONFIG) as rec:
        loop = rec.channel("loop", list(LOOP_FIELDS))
        ref = rec.channel("reference", list(REFERENCE_FIELDS))
        for k in parts:
            loop.append(_rows(k))
            ref.append(_reference(k))
        for t_loop, kind, cause in faults:
            rec.mark("fault", t_loop=t_loop, kind=kind, cause=cause, action="safe state")
        rec.mark("fault", kind="imu", cause="an older mark without loop time")


def _export(monkeypatch, capsys, rec: Path, out: Path, *more: str) -> tuple[int, str, str]:
    monkeypatch.setitem(cli.COMMANDS, "export", "tvsd.cli.export")
    status = cli.main(["export", str(rec), "--csv", str(out), *more])
    got, err = capsys.readouterr()
    return status, got, err


def test_gaps_are_filled_flagged_and_listed_and_the_csv_reads_back(tmp_path, monkeypatch, capsys):
    k1, k2, k3 = np.arange(0, 100), np.arange(130, 300), np.arange(302, 400)  # 30 and 2 samples lost
    _record(tmp_path / "rec", [k1, k2, k3])
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    assert "2 gap(s), 32 sample(s) missing" in err and "--strict" in err
    csv = read_csv(tmp_path / "o.csv")  # uniform t: the recording CSV contract holds
    assert len(csv.t) == 400 and csv.sample_rate_hz == pytest.approx(1000)
    gap = csv.extra["gap"]
    assert np.array_equal(np.nonzero(gap)[0], np.r_[100:130, 300:302])
    known = gap == 0
    k = np.arange(400)
    # Known samples are the recorded ones (%.9g: relative 1e-8); filled ones lie on the line
    # between their neighbours (linear interpolation, exact up to the same rounding).
    np.testing.assert_allclose(csv.u[known], _rows(k)["u"][known], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(csv.u[100:130], np.interp(k[100:130], [99, 130], csv.u[[99, 130]]), atol=1e-8)
    assert csv.meta["gaps"] == "2" and csv.meta["gap_samples"] == "32"
    assert csv.meta["gap_1"].startswith("after t=0.099 s, 30 samples (30 ms)")


def test_strict_refuses_the_gap_as_before(tmp_path, monkeypatch, capsys):
    _record(tmp_path / "rec", [np.arange(0, 100), np.arange(130, 200)])
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv", "--strict")
    assert status == 2 and len(err.strip().splitlines()) == 1 and "30 samples missing" in err
    assert not (tmp_path / "o.csv").exists()


def test_a_bin_recorded_twice_is_written_once(tmp_path, monkeypatch, capsys):
    """Recordings made before ticks moved by number hold repeated 1 kHz bins: kept once, counted."""
    _record(tmp_path / "rec", [np.arange(0, 120), np.arange(110, 200)])
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    csv = read_csv(tmp_path / "o.csv")
    assert len(csv.t) == 200 and csv.meta["duplicate_rows_dropped"] == "10" and csv.meta["gaps"] == "0"


def test_the_reference_the_unit_and_the_fault_marks_are_exported(tmp_path, monkeypatch, capsys):
    k = np.arange(0, 500)
    faults = [(T0 + 0.2504, "mcu_stale", "MCU state frames stopped: none for 40 ms")]
    _record(tmp_path / "rec", [k], faults)
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    csv = read_csv(tmp_path / "o.csv")
    assert csv.meta["u_unit"] == "V"
    header = (tmp_path / "o.csv").read_text().splitlines()
    columns = next(line for line in header if not line.startswith("#")).split(",")
    assert columns[:9] == ["t", "u", "omega", "phi", "omega_ref", "phi_ref", "u_ff", "gap", "fault"]
    np.testing.assert_allclose(csv.extra["phi_ref"], k * 0.16, rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(csv.extra["omega_ref"], 157.0)
    assert np.nonzero(csv.extra["fault"])[0].tolist() == [250]  # 0.2504 s: the 1 ms sample 250
    assert csv.meta["faults"] == "1"
    assert csv.meta["fault_1"] == "t=0.250 s, mcu_stale: MCU state frames stopped: none for 40 ms"
    assert csv.meta["faults_not_placed"] == "1"  # the mark without loop time


def test_the_identify_excitation_is_exported_as_u_exc_averaged_per_sample(tmp_path, monkeypatch, capsys):
    """The `excitation` channel (identify's table, rows 1 ms long on the loop's clock) becomes u_exc:
    the exact mean of the played step function over each 1 ms bin (bins end at their t). Rows start
    half a bin off the grid, so each bin holds half of two rows; after an aborted run's end mark the
    rows were never played: 0 there, as before the run."""
    k = np.arange(0, 300)
    with Recorder(tmp_path / "rec", CONFIG) as rec:
        rec.channel("loop", list(LOOP_FIELDS)).append(_rows(k))
        rec.channel("reference", list(REFERENCE_FIELDS)).append(_reference(k))
        j = np.arange(100)
        v = np.where(np.random.default_rng(3).random(100) < 0.5, -0.5, 0.5)
        exc = rec.channel("excitation", [("t", "<f8"), ("d_rps", "<f8"), ("d_volts", "<f8")])
        exc.append({"t": T0 + 0.1005 + j / 1000, "d_rps": np.zeros(100), "d_volts": v})
        rec.mark("identify_start", t_loop=T0 + 0.1, t0=T0 + 0.1005, lines_hz=[8.0, 0.2, 0.6000000000000001])
        rec.mark("identify_end", t_loop=T0 + 0.150, outcome="aborted", reason="a fault")
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    csv = read_csv(tmp_path / "o.csv")
    header = (tmp_path / "o.csv").read_text().splitlines()
    columns = next(line for line in header if not line.startswith("#")).split(",")
    assert columns[:10] == ["t", "u", "omega", "phi", "omega_ref", "phi_ref", "u_ff", "u_exc", "gap", "fault"]
    assert csv.excitation_hz == (0.2, 0.6, 8.0)  # identify's multisine lines, from its start mark
    played = v[:50]  # rows from 0.1505 s on come after the abort mark (0.150 s)
    want = np.zeros(len(k))
    # bin k is (k − 1 … k) ms after T0; row j (0.1005 + j/1000 s on) is half in bin 101 + j, half
    # in bin 102 + j
    want[101] = 0.5 * played[0]
    want[102:151] = 0.5 * (played[:-1] + played[1:])
    want[151] = 0.5 * played[-1]
    np.testing.assert_allclose(csv.extra["u_exc"], want, atol=1e-9)


def test_a_recording_without_identify_has_no_u_exc(tmp_path, monkeypatch, capsys):
    _record(tmp_path / "rec", [np.arange(0, 100)])
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    assert "u_exc" not in read_csv(tmp_path / "o.csv").extra


@pytest.mark.parametrize("name", ["seg-00000.tvsrec", "seg-0000.tvsrec", "rec.csv"])
def test_export_never_writes_into_the_recording(tmp_path, monkeypatch, capsys, name):
    """`--csv REC/seg-00000.tvsrec` overwrote the recording with its CSV (data lost); another
    seg-*.tvsrec name beside it made every later export fail ('not a tvsd recording segment')."""
    rec = tmp_path / "rec"
    _record(rec, [np.arange(0, 3000)])
    before = {p.name: p.read_bytes() for p in rec.iterdir()}
    status, _, err = _export(monkeypatch, capsys, rec, rec / name)
    assert status == 2 and "inside the recording" in err and err.count("\n") == 1, err
    assert {p.name: p.read_bytes() for p in rec.iterdir()} == before
    assert _export(monkeypatch, capsys, rec, tmp_path / "ok.csv")[0] == 0


def test_export_of_a_segment_file_never_writes_over_it(tmp_path, monkeypatch, capsys):
    rec = tmp_path / "rec"
    _record(rec, [np.arange(0, 3000)])
    (seg,) = rec.glob("seg-*.tvsrec")
    before = seg.read_bytes()
    status, _, err = _export(monkeypatch, capsys, seg, seg)
    assert status == 2 and "is the recording" in err and seg.read_bytes() == before, err


def test_u_is_what_the_pwm_frames_told_the_drive(tmp_path, monkeypatch, capsys):
    """With a `pwm` channel (the frames the daemon sent: loop time, volts), u is their held value
    averaged over each 1 ms bin (bins end at their t; a frame holds until the next), and the law's
    1 ms mean moves to u_law. Frames at 2 kHz alternating 4 V and 8 V give 6 V in every bin they
    cover, whatever the law's mean said; a bin that began before the first frame keeps the law's
    value; after the last frame its 8 V holds (the MCU keeps a duty until the next frame)."""
    k = np.arange(0, 300)
    with Recorder(tmp_path / "rec", CONFIG) as rec:
        rec.channel("loop", list(LOOP_FIELDS)).append(_rows(k))
        rec.channel("reference", list(REFERENCE_FIELDS)).append(_reference(k))
        j = np.arange(200)
        volts = np.where(j % 2 == 0, 4.0, 8.0)
        rec.channel("pwm", list(PWM_FIELDS)).append({"t": T0 + 0.0502 + j * 0.0005, "volts": volts})
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    csv = read_csv(tmp_path / "o.csv")
    law = _rows(k)["u"]
    np.testing.assert_allclose(csv.extra["u_law"], law, atol=1e-8)
    np.testing.assert_allclose(csv.u[:51], law[:51], atol=1e-8)  # bin 50 ends at 0.050 s: before the first
    np.testing.assert_allclose(csv.u[52:150], 6.0, atol=1e-8)
    np.testing.assert_allclose(csv.u[151:], 8.0, atol=1e-8)  # the last frame, sent at 0.1497 s
    assert "PWM frames" in csv.meta["u_source"]
