"""The peak test's likelihood ratios on a residual whose segments differ in level: rows left out as
zeros where the shaft was stuck (peak.segment_share, docs/measurements/res17.md).

The family is PEAK_WHITE_LR's calibration family (flat + differentiated measurement noise in any
mix, 250 Hz rows, 30 s; tvsd.analysis.peak), each draw also with its first 30–50 % left out."""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

from tvsd.analysis import noise, peak

RATE, N = 250.0, 7500


def _null(rng: np.random.Generator) -> np.ndarray:
    mix = rng.uniform(0.0, 1.0)
    diff = np.diff(rng.standard_normal(N + 1)) / 2.0
    return math.sqrt(1.0 - mix) * rng.standard_normal(N) + math.sqrt(mix) * diff


def _stuck(rng: np.random.Generator, x: np.ndarray) -> np.ndarray:
    y = x.copy()
    y[: int(rng.uniform(0.3, 0.5) * len(x))] = 0.0
    return y


def test_a_stuck_stretch_does_not_inflate_the_peak_ratio() -> None:
    """The same draw with its first 30–50 % left out carries 50–70 % of the data: its peak ratio,
    counted on every segment, read 1.56× the whole record's (median of these 40 draws), and 1 of
    them passed the resonance gate. Counted on the segments' equal-level equivalent it is the
    whole record's in law: the paired ratio's median is 1.06 here; 1.3 is far outside its
    scatter over 40 draws and well below the 1/(kept share) ≈ 1.7 the count gives."""
    rng = np.random.default_rng(20261128)
    ratios, named = [], 0
    for _ in range(40):
        x = _null(rng)
        whole = noise.analyse(x, RATE, 1.0, 100.0)
        gapped = noise.analyse(_stuck(rng, x), RATE, 1.0, 100.0)
        ratios.append(gapped.peak_white_lr / max(whole.peak_white_lr, 1e-9))
        named += noise.spectral_cause(gapped, noise.COLOUR_P) == "resonance"
    assert float(np.median(ratios)) < 1.3, np.median(ratios)
    assert named == 0


def test_the_share_is_one_on_equal_segments_and_the_kept_share_on_zeros() -> None:
    """Its two ends from first principles: segments of one level count fully (to within the
    levels' own sampling scatter, ≈ 1/nper), and a record half zeros counts as its half."""
    rng = np.random.default_rng(7)
    x = rng.standard_normal(N)
    assert abs(peak.segment_share(x, 1000) - 1.0) < 0.01
    y = x.copy()
    y[: N // 2] = 0.0
    assert 0.4 < peak.segment_share(y, 1000) < 0.6


def test_modes_in_a_gapped_record_are_still_named() -> None:
    """Modes of stated size in the same gapped family — a lightly damped mode (Q 30–200,
    5–45 Hz) whose rms is 0.3 of the noise's — stay named, all 20 (each one's ratio is in the
    hundreds: halving it leaves it far above the gate)."""
    rng = np.random.default_rng(20261129)
    named = 0
    for _ in range(20):
        x = _null(rng)
        f0, q = rng.uniform(5.0, 45.0), 10 ** rng.uniform(1.5, 2.3)
        w0 = 2 * math.pi * f0 / RATE
        r = math.exp(-w0 / (2 * q))
        m = lfilter([1.0], [1.0, -2 * r * math.cos(w0), r * r], rng.standard_normal(N))
        x = x + 0.3 * m / m.std() * x.std()
        rep = noise.analyse(_stuck(rng, x), RATE, 1.0, 100.0)
        named += noise.spectral_cause(rep, noise.COLOUR_P) == "resonance" and abs(rep.peak_hz - f0) < 0.5
    assert named == 20, named
