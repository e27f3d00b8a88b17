"""The encoder's quantisation floor for a speed interpolated between encoder frames (issue 12,
docs/measurements/closedcolour2.md). `tvsctl export` writes ω as the difference over each sample
of the angle read off the line between the MCU's frames (tvsd/cli/export_states.py): off the count
grid, so before this the doctor had no floor for it, and SIL daemon identify exports of a white
plant read the count's f⁴ power as a 3–10 ms colour (docs/measurements/closedcolour.md). The
export now declares the counts and the frames' timing; the floor follows the interpolation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import welch
from test_export_states import T0, _recording

from tvsd.analysis import quantisation
from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.cli.export_states import from_states
from tvsd.config import load_config
from tvsd.recording.csvfile import read as read_csv
from tvsd.recording.csvfile import write

FS = 1000.0
COUNTS = 8192
Q = 2 * math.pi / COUNTS


def _frames(rate: float, offset: float, n: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Frame instants (offset after the sample edges k/FS) and the shaft's angle there: 25 rev/s
    and a random walk of ~20 counts per frame, so the count's error is white at the frames."""
    t = offset - 2 / rate + np.arange(int((n + 4) / FS * rate)) / rate
    walk = np.cumsum(np.random.default_rng(seed).normal(0.0, 20 * Q, len(t)))
    return t, 157.0 * t + walk


def _interpolated(t: np.ndarray, angle: np.ndarray, n: int) -> np.ndarray:
    """ω of the export (from_states) from these frames: their placed instants are their own."""
    rows = np.zeros(len(t), dtype=[("t", float), ("mcu_ticks", np.int64), ("phi", float)])
    rows["t"], rows["mcu_ticks"], rows["phi"] = t, np.round(t * 16e6), angle
    out = from_states(rows, 1.0 / FS, n, 1.0 / FS, np.zeros(n), np.zeros(n))
    assert out is not None and out[2] == n
    return out[0]


@pytest.mark.parametrize(("rate", "offset"), [(2000.0, 0.15e-3), (1000.0, 0.3e-3), (2000.0, 0.0)])
def test_the_interpolated_angles_error_has_the_derived_spectrum(rate: float, offset: float) -> None:
    """ω's quantisation error (the export's ω from whole counts minus from the exact angles) has
    the PSD fs²·4·sin²(πf/fs)·q²/(6·fs)·gain(f): at 2 kHz frames 0.15 ms after the edges a white
    error of (1 − a)² + a² = 0.58 of the on-grid one (a = 0.7), at 1 kHz frames 0.3 ms after a
    low-pass one (neighbouring edges share a frame), with frames on the edges the on-grid one.
    Compared in quarter-bands of [0, fs/2]: 120 s give ~230 Welch segments (1024 samples, 50 %
    overlap), so each quarter's mean ratio (128 bins) has a relative sd ≈ 1/√(230·128/2) < 1 %;
    6 % is > 6 sd and still tells 0.58 from the random-phase 2/3 and from 1."""
    n = 120_000
    t, angle = _frames(rate, offset, n)
    err = _interpolated(t, np.floor(angle / Q) * Q, n) - _interpolated(t, angle, n)
    f, p = welch(err, fs=FS, nperseg=1024)
    gain = quantisation.interpolation_gain(FS, rate, offset)
    predicted = (FS * 2 * np.sin(np.pi * f / FS)) ** 2 * Q * Q / (6 * FS) * gain(f)
    for lo in (0.0, 125.0, 250.0, 375.0):
        band = (f > max(lo, 20.0)) & (f < lo + 125.0)
        assert np.mean(p[band] / predicted[band]) == pytest.approx(1.0, abs=0.06), (lo, rate, offset)
    if rate == 2000.0 and offset > 0:
        assert gain(np.array([10.0]))[0] == pytest.approx(0.3**2 + 0.7**2)


@pytest.mark.parametrize("rate", [0.1, 1e-9])
def test_frames_far_slower_than_the_samples_give_a_finite_non_negative_gain(rate: float) -> None:
    """`# encoder_frame_hz:` only has to be > 0 (recording.csvfile). Before: 1e-9 Hz asked for a
    2·10¹² lag autocovariance (MemoryError, `tvsctl analyze` exit 70), and at 0.1 Hz, the lags
    reaching the n edges, the per-pair mean made the gain negative (−15: a negative floor, NaN in
    the colour test's log). A PSD is never negative: the weights' periodogram is not."""
    f = np.linspace(0.0, FS / 2, 2001)
    gain = quantisation.interpolation_gain(FS, rate, 0.0)(f)
    assert np.all(np.isfinite(gain)) and float(gain.min()) >= 0.0


def _export_like(path: Path, rate: float, offset: float, declare: bool) -> Path:
    n = 30_000
    t, angle = _frames(rate, offset, n, seed=5)
    omega = _interpolated(t, np.floor(angle / Q) * Q, n)
    phi = np.cumsum(omega) / FS
    ts = np.arange(n) / FS
    u = 0.05 * omega + np.random.default_rng(6).normal(0, 0.1, n)
    meta: dict[str, object] = {"encoder_counts_per_rev": COUNTS}
    if declare:
        meta |= {"encoder_frame_hz": rate, "encoder_frame_offset_s": offset}
    write(path, ts, u, omega, phi, FS, meta)
    return path


def test_the_doctor_has_the_floor_of_an_interpolated_speed(tmp_path: Path) -> None:
    """Before: ω off the count grid → `quantisation.floor` None (the count's f⁴ power unknown to the
    colour test). With the frames declared: a floor, (1 − a)² + a² = 0.58 times the on-grid one of
    the same encoder (frames on the edges: ω the count difference, the count-step path). Compared
    per octave: the on-grid floor is a histogram of the sawtooth's lines placed by the speed, not
    exactly white (tests/test_retimed_floor.py: octaves within 7 %); 10 % allows for that."""
    cfg = load_config()
    framed = load(_export_like(tmp_path / "f.csv", 2000.0, 0.15e-3, True), cfg)
    bare = load(_export_like(tmp_path / "b.csv", 2000.0, 0.15e-3, False), cfg)
    grid = load(_export_like(tmp_path / "g.csv", 1000.0, 0.0, False), cfg)
    prep = prepare(framed, Band())
    keep = np.ones(len(prep.rows(prep.accel)))
    assert quantisation.floor(prepare(bare, Band()), keep) is None  # undeclared: no floor, as before
    on_grid = quantisation.floor(prepare(grid, Band()), keep)
    assert quantisation.count_step(prepare(grid, Band())) is not None and on_grid is not None
    interp = quantisation.floor(prep, keep)
    assert interp is not None
    f = np.linspace(1.0, 50.0, 4901)
    for lo in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        band = (f >= lo) & (f < min(2 * lo, 50.0))
        ratio = interp(f)[band].sum() / on_grid(f)[band].sum()
        assert ratio == pytest.approx(0.58, rel=0.10), lo


def test_the_export_declares_the_encoder_and_its_frames(tmp_path, monkeypatch, capsys) -> None:
    """`# encoder_counts_per_rev:` from the daemon's config (the setting's default, 8192, where its
    `mcu` section has none) and the frames' rate and offset after the sample edges."""
    from test_export import _export

    frames_t = T0 - 0.01 + 0.2e-3 + np.arange(900) * 5e-4  # 2 kHz, 0.2 ms after each bin's end
    _recording(tmp_path / "rec", frames_t, frames_t)
    assert _export(monkeypatch, capsys, tmp_path / "rec", tmp_path / "o.csv")[0] == 0
    meta = read_csv(tmp_path / "o.csv").meta
    assert meta["encoder_counts_per_rev"] == "8192"
    assert float(meta["encoder_frame_hz"]) == pytest.approx(2000.0, rel=1e-6)
    assert float(meta["encoder_frame_offset_s"]) == pytest.approx(0.2e-3, abs=1e-7)


@pytest.mark.parametrize(
    ("lines", "word"),
    [
        ("# encoder_counts_per_rev: 8192\n# encoder_frame_hz: 2000\n", "go together"),
        ("# encoder_frame_hz: 2000\n# encoder_frame_offset_s: 0.0002\n", "go together"),
        ("# encoder_counts_per_rev: 8192\n# encoder_frame_hz: fast\n# encoder_frame_offset_s: 0\n", "'fast'"),
        ("# encoder_counts_per_rev: 8192\n# encoder_frame_hz: 2000\n# encoder_frame_offset_s: -1\n", "'-1'"),
    ],
)
def test_bad_frame_lines_get_one_line(tmp_path: Path, lines: str, word: str) -> None:
    """A frame line without its partner or the counts, or not a number: one line naming the row."""
    from tvsd.errors import DataFileError

    path = tmp_path / "bad.csv"
    body = "".join(f"{k / 1000},0.1,1.0,{k / 1000}\n" for k in range(50))
    path.write_text("# tvs-recording: 1\n# sample_rate_hz: 1000\n" + lines + "t,u,omega,phi\n" + body)
    with pytest.raises(DataFileError) as err:
        read_csv(path)
    assert word in str(err.value) and "\n" not in str(err.value)
