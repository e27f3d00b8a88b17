"""The delay's timing reference: ω the period mean, u as `# u_sampling:` says (tvsd/analysis/timing.py).

A speed column whose timing is not the period mean (a control thread's speed logged late, a
speed sampled at the instant) shifts the whole response, and the doctor read the shift as a
`delay`: a SIL null with ω one sample late was named `delay` 1.08 ms (z 4.6), three samples late
3.07 ms (z 69.5) — where the 1 ms SIL delay reads 1.14 ms (z 5.3). φ carries the reference
(its backward difference is the period mean), so the lag is measured and undone on load. And
`tvsctl export` declares its u's sampling, so the doctor reads the daemon's recordings against
their own convention (docs/measurements/lagref.md).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_export import _export, _record

from tvsd.analysis import timing
from tvsd.cli.main import main
from tvsd.recording.csvfile import read, write


def _period_mean_pair(rng: np.random.Generator, n: int, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """φ of a shaft whose speed wanders in band (a PRBS-driven run), and its period-mean speed."""
    w = 100.0 + np.convolve(rng.standard_normal(n), np.ones(40) / 40, mode="same") * 60.0
    phi = np.cumsum(w) / fs
    return phi, timing.reference_speed(w, phi, fs)


@pytest.mark.parametrize("lag", [1.0, 2.3, -0.5])
def test_a_shifted_speed_is_measured_and_a_noisy_one_is_left_alone(lag: float) -> None:
    fs, n = 1000.0, 20000
    rng = np.random.default_rng(12)
    phi, wbar = _period_mean_pair(rng, n, fs)
    late = timing.retimed(wbar, -lag) + rng.normal(0.0, 0.02 * np.std(wbar), n)
    got, share = timing.speed_lag(late, phi, fs)
    # The scan's parabola resolves a shift of a band-limited signal to well under its 0.05 grid;
    # 0.02 samples is ~10 times the estimate's scatter at this noise (2 % of the signal).
    assert abs(got - lag) < 0.02 and share > 0.9 and timing.off_reference(got, share)
    # The same speed with an in-band noise 3x its shift's own difference (a tach's): a shift
    # explains little of what separates it from the period mean, so it is not moved.
    noisy = wbar + np.convolve(rng.standard_normal(n), np.ones(5) / 5, mode="same") * 3 * np.std(wbar - late)
    got, share = timing.speed_lag(noisy, phi, fs)
    assert not timing.off_reference(got, share), (got, share)


def _analyze(path: Path, capsys: pytest.CaptureFixture[str]) -> dict:
    assert main(["analyze", str(path), "--json", "--quiet"]) == 0
    return json.loads(capsys.readouterr().out)


def _late_speed(src: Path, dst: Path, samples: int) -> None:
    rec = read(src)
    omega = np.concatenate([np.full(samples, rec.omega[0]), rec.omega[:-samples]])
    meta = {k: v for k, v in rec.meta.items() if k not in ("tvs-recording", "sample_rate_hz")}
    write(dst, rec.t, rec.u, omega, rec.phi, rec.sample_rate_hz, meta, rec.extra)


@pytest.mark.slow
def test_a_late_speed_column_is_not_a_delay(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Before: `delay` 1.08 ms (1 sample late) and 3.07 ms (3 samples) on a SIL null. (The 1 ms
    SIL delay of the same seed, whose ω is on time, stays named with its size: the next test.)"""
    from tvsd.config import load_config
    from tvsd.sim.record import record

    null = tmp_path / "null.csv"
    record(load_config(), null, "steps", 30.0, (), seed=3)
    for samples in (1, 3):
        late = tmp_path / f"late{samples}.csv"
        _late_speed(null, late, samples)
        got = _analyze(late, capsys)
        assert got["cause"] != "delay", got["effect"]
        # the move is said, in the JSON and in the sentence (review: it was silent)
        assert [w["code"] for w in got.get("warnings", [])].count("omega_retimed") == 1, got.get("warnings")
        assert "advanced by it" in got["summary"]


def test_export_declares_that_u_is_the_period_mean(tmp_path: Path, monkeypatch, capsys) -> None:
    """`tvsctl export`'s u (the frames sent or the law's, each a mean over the 1 ms bin that ends at
    the row's time) is tvsd's convention: said so, the doctor's delay is not a sample unsure."""
    _record(tmp_path / "rec", [np.arange(0, 400)])
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    assert read(tmp_path / "o.csv").meta["u_sampling"] == "mean"


@pytest.mark.slow
def test_a_daemon_recording_exported_keeps_a_one_sample_delay(tmp_path: Path, monkeypatch, capsys) -> None:
    """The daemon's writer → `tvsctl export` → `tvsctl analyze`: a loop channel holding a SIL run
    with a 1 ms delay (u and omega the 1 ms means the daemon records). Before the export said how
    u was sampled, the doctor could not tell one sample of convention from the delay and did not
    name it (`sampling_convention`, 1.14 ms under two samples); declared, it is named."""
    from test_export import T0

    from tvsd.causes import parse_effect
    from tvsd.config import load_config
    from tvsd.recording.format import LOOP_FIELDS
    from tvsd.recording.writer import Recorder
    from tvsd.sim.record import record

    sim = tmp_path / "sim.csv"
    record(load_config(), sim, "steps", 30.0, (parse_effect("delay:delay_s=0.001"),), seed=3)
    run = read(sim)
    with Recorder(tmp_path / "rec", "plant:\n  name: bench\n") as rec:
        loop = rec.channel("loop", list(LOOP_FIELDS))
        loop.append({"t": T0 + run.t, "u": run.u, "omega": run.omega, "phi": run.phi})
    status, _, err = _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")
    assert status == 0, err
    got = _analyze(tmp_path / "o.csv", capsys)
    # 1 ms at 1 kHz plus the SIL drive's L/R (0.12 ms): 1.14 ms on this seed, within a third of a
    # sample of the truth (the refit's fraction resolves a sample to ~0.1 here).
    assert got["cause"] == "delay" and abs(got["effect"]["delay_s"] - 1.1e-3) < 0.35e-3, got
