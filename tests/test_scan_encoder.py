"""β from the encoder: the count quantisation bound is honest where phases spread and where they
do not (a whole number of counts per sample)."""

from __future__ import annotations

import math

import numpy as np

from tvsd.scan.encoder import EncoderLog

CPR = 8192
DT = 1e-4


def log(counts_per_sample: float, seconds: float = 2.0, phase: float = 0.37) -> EncoderLog:
    t = np.arange(round(seconds / DT)) * DT
    counts = np.floor(phase + counts_per_sample * t / DT).astype(np.int64)
    return EncoderLog(t, counts, CPR)


def test_spread_phases_read_the_angle_to_a_fraction_of_a_count():
    cps = 16.384  # 20 rev/s: the sub-count phase steps by 0.384 per sample
    enc = log(cps)
    t = np.random.default_rng(0).uniform(0.01, 1.99, 2000)
    angle, var, speed = enc.angle(t, 5e-4)
    true = (0.37 + cps * t / DT) * 2 * math.pi / CPR
    err_counts = (angle - true) * CPR / (2 * math.pi)
    sigma_counts = np.sqrt(var) * CPR / (2 * math.pi)
    # 11 samples with spread phases pin the line to ~1/11 count; a single read is 0.29 count.
    assert np.std(err_counts) < 0.08 and np.mean(sigma_counts) < 0.1
    # The reported spread is the error's (2000 reads: ±2σ covers ~95 %, ≥ 90 % allows 3σ sampling).
    assert np.mean(np.abs(err_counts) <= 2 * sigma_counts) >= 0.90
    # The speed from ±2.5 ms of counts: ±1 count over 5 ms is 2e-4 of the 819 counts there.
    np.testing.assert_allclose(speed, cps / DT * 2 * math.pi / CPR, rtol=5e-4)


def test_locked_phases_report_a_whole_count():
    enc = log(12.0)  # 14.65 rev/s: every sample sees the same sub-count phase
    t = np.random.default_rng(1).uniform(0.01, 1.99, 500)
    _, var, _ = enc.angle(t, 5e-4)
    sigma_counts = np.sqrt(var) * CPR / (2 * math.pi)
    # Nothing averages: the band is the whole count, σ ≈ 1/√12 = 0.29 count.
    assert np.all(sigma_counts > 0.25)
