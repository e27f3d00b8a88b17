"""`tvsctl bench --only fuzz`: the protocol fuzz as a bench group (tvsd/hw/mcu/fuzz_bench.py).

Short runs (a few thousand damaged frames): the figures at 10^6 are measured by the bench itself."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tvsd.cli.main import main
from tvsd.errors import EXIT_USAGE
from tvsd.hw.mcu import fuzz_bench


def _bench(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    status = main(["bench", "--only", "fuzz", "--json", *argv])
    out = capsys.readouterr().out
    assert status == 0, out
    return json.loads(out)


def test_both_decoders_in_a_checkout(capsys: pytest.CaptureFixture[str]) -> None:
    """In a source checkout the C harness is built with make and run beside the Python decoder.
    At 5000 damaged frames a CRC-32 false accept is expected 2e-6 times: any is a bug."""
    res = _bench(capsys, "--frames", "5000")
    assert res["fuzz_damaged_frames_per_side"] == 5000
    assert res["fuzz_c_false_accepts"] == 0 and res["fuzz_c_duplicates_executed"] == 0
    assert res["fuzz_py_false_accepts"] == 0 and res["fuzz_py_duplicates_executed"] == 0
    assert res["fuzz_c_wall_s"] >= 0 and res["fuzz_py_wall_s"] > 0
    assert float(res["fuzz_theoretical_false_accepts_per_damaged_frame"]) == pytest.approx(4.66e-10, rel=0.01)


def test_without_a_checkout_the_python_side_still_runs(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """An installed wheel has no firmware/ tree: the C side says how to run it, the rest runs."""
    monkeypatch.setattr(fuzz_bench, "FIRMWARE_DIR", tmp_path / "firmware")
    res = _bench(capsys, "--frames", "2000")
    assert "make -C firmware fuzz" in res["fuzz_c"] and "fuzz_c_false_accepts" not in res
    assert res["fuzz_py_false_accepts"] == 0


def test_false_accepts_are_reported_when_there_are_some(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The figure is counted, not assumed: a decoder checking only 4 CRC bits lets about 1 in 16
    damaged candidates through, so 2000 damaged frames give dozens of false accepts."""
    from tvsd.hw.mcu.fuzz import TruncatedCheckDecoder, fuzz_decoder

    def weak(frames: int, seed: int = 1):  # type: ignore[no-untyped-def]
        return fuzz_decoder(frames, seed, make_decoder=lambda s: TruncatedCheckDecoder(s, 4))

    monkeypatch.setattr(fuzz_bench, "FIRMWARE_DIR", tmp_path / "firmware")
    monkeypatch.setattr(fuzz_bench, "fuzz_decoder", weak)
    res = _bench(capsys, "--frames", "2000")
    assert res["fuzz_py_false_accepts"] > 10


def test_frames_must_be_positive(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        main(["bench", "--only", "fuzz", "--frames", "0"])
    err = capsys.readouterr().err
    assert e.value.code == EXIT_USAGE
    assert "--frames: expected a whole number of frames 1..1000000000, got '0'" in err
    assert "Traceback" not in err
