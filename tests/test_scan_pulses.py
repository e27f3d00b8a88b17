"""Pulse bookkeeping and β from pulses: anomalies are counted and never become points; the
estimators are exact where their assumptions hold, and compensation removes what the IMU knows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tvsd.scan import beta as B
from tvsd.scan.compensation import KnownAccel
from tvsd.scan.pulses import OPTICAL, ZERO, clean

TICK = 1e-9  # a fine timer, so quantisation (ω·1 ns ≈ 1e-7 rad) stays below every tolerance here
OMEGA = 2 * math.pi * 20.0
BETA = 1.9


def stream(zero_t: np.ndarray, opt_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    kind = np.concatenate([np.full(len(zero_t), ZERO), np.full(len(opt_t), OPTICAL)])
    t = np.concatenate([zero_t, opt_t])
    order = np.argsort(t, kind="stable")
    return kind[order], np.round(t[order] / TICK).astype(np.int64)


def uniform(revs: int = 40) -> tuple[np.ndarray, np.ndarray]:
    zero = np.arange(revs + 1) * 2 * math.pi / OMEGA
    return zero, zero[:-1] + BETA / OMEGA


def test_anomalies_are_counted_and_dropped():
    zero, opt = uniform()
    period = 2 * math.pi / OMEGA
    zero = np.sort(np.concatenate([np.delete(zero, 12), [zero[5] + 0.01 * period]]))  # miss 12, double 5
    opt = np.sort(np.concatenate([np.delete(opt, 25), [opt[20] + 1e-4]]))  # miss 25, echo in 20
    kind, ticks = stream(zero, opt)
    # Optical pulse 30 arrives after zero pulse 31: out of order.
    i = int(np.flatnonzero((kind == OPTICAL) & (ticks == round(uniform()[1][30] / TICK)))[0])
    kind[[i, i + 1]], ticks[[i, i + 1]] = kind[[i + 1, i]], ticks[[i + 1, i]]
    cp = clean(kind, ticks, TICK)
    s = cp.stats
    assert (s.out_of_order, s.doubled_zero, s.missed_zero) == (1, 1, 1)
    assert s.doubled_optical == 2  # both pulses of revolution 20: the echo cannot be told apart
    assert s.optical_in_gap == 2  # revolutions 11 and 12 have no closing zero pulse
    assert s.missed_optical == 2  # 25 (missing) and 30 (dropped out of order)
    est = B.estimate(cp, "centred")
    revs = np.round(est.t / period - BETA / (2 * math.pi)).astype(int)
    # Revolution 0 has no zero pulse before it, 13 none at n−1 (12 was missed).
    assert sorted(set(range(40)) - set(revs)) == [0, 11, 12, 13, 20, 25, 30]
    assert est.dropped == 2
    np.testing.assert_allclose(est.beta, BETA, atol=1e-6)


def test_uniform_speed_is_exact_for_every_method():
    kind, ticks = stream(*uniform())
    cp = clean(kind, ticks, TICK)
    for method in ("naive", "causal", "centred"):
        est = B.estimate(cp, method)
        # Quantisation bound: ω·TICK·(1 + Σ|w|) ≤ 126·1e-9·6 < 1e-6 rad.
        np.testing.assert_allclose(est.beta, BETA, atol=1e-6, err_msg=method)


def _profile(t: np.ndarray, alpha: float, amp: float, freq: float) -> np.ndarray:
    """φ(t) = ω0·t + α·t²/2 + amp/Ω²·(Ω·t − sin Ω·t): acceleration α + amp·sin Ω·t."""
    w = 2 * math.pi * freq
    return OMEGA * t + 0.5 * alpha * t * t + amp / (w * w) * (w * t - np.sin(w * t))


def _crossings(levels: np.ndarray, alpha: float, amp: float, freq: float) -> np.ndarray:
    t = levels / OMEGA
    w = 2 * math.pi * freq
    for _ in range(30):  # Newton on φ(t) = level; φ' ≥ ω0 − |α|·t − ... stays ≫ 0 here
        speed = OMEGA + alpha * t + amp / w * (1 - np.cos(w * t))
        t = t - (_profile(t, alpha, amp, freq) - levels) / speed
    return t


def test_quadratic_fit_follows_acceleration_the_naive_reading_does_not():
    levels = 2 * math.pi * np.arange(41)
    zero = _crossings(levels, 30.0, 0.0, 1.0)
    opt = _crossings(levels[:-1] + BETA, 30.0, 0.0, 1.0)
    cp = clean(*stream(zero, opt), TICK)
    # A quadratic φ(t) is what the centred and causal fits reproduce exactly.
    for method in ("centred", "causal"):
        np.testing.assert_allclose(B.estimate(cp, method).beta, BETA, atol=1e-6, err_msg=method)
    # The uniform-speed reading with the previous period: β̂ = Δt·(ω_k − α·T/2) while
    # β = ω_k·Δt + α·Δt²/2, so β̂ − β ≈ −α·Δt·(Δt + T)/2 (first order in α·T/ω ≈ 0.01).
    est = B.estimate(cp, "naive")
    dt_o = est.t - est.knots[:, 1]
    period = est.knots[:, 1] - est.knots[:, 0]
    np.testing.assert_allclose(est.beta - BETA, -30.0 * dt_o * (dt_o + period) / 2, rtol=0.03)


def test_compensation_removes_the_known_acceleration():
    amp, freq = 20.0, 37.0  # not locked to the rotation, not a polynomial over three revolutions
    levels = 2 * math.pi * np.arange(41)
    zero = _crossings(levels, 0.0, amp, freq)
    opt = _crossings(levels[:-1] + BETA, 0.0, amp, freq)
    cp = clean(*stream(zero, opt), TICK)
    # The IMU's 1 ms samples: exact means of the acceleration over each sample.
    dt = 1e-3
    edges = np.arange(-0.01, zero[-1] + 0.02, dt)
    w = 2 * math.pi * freq
    means = amp * (np.cos(w * edges[:-1]) - np.cos(w * edges[1:])) / (w * dt)
    known = KnownAccel.build(edges[0], dt, means)
    plain = B.estimate(cp, "centred").beta - BETA
    comp = B.estimate(cp, "centred", known).beta - BETA
    assert np.std(plain) > 1e-4  # amp/Ω² = 3.7e-4 rad of speed wobble the pulses cannot see
    # Left: the within-sample shape of the acceleration, amp·Ω·dt³/12 = 3.9e-7 rad per sample,
    # adding up over the ~13 samples of a half period of the 37 Hz wobble: ≲ 5e-6 rad.
    assert np.max(np.abs(comp)) < 1e-5
    assert np.max(np.abs(comp)) < np.std(plain) / 50


def test_unknown_method_and_mismatched_arrays_are_refused():
    cp = clean(*stream(*uniform(5)), TICK)
    with pytest.raises(ValueError, match="unknown β method"):
        B.estimate(cp, "psychic")
    with pytest.raises(ValueError, match="same length"):
        clean(np.zeros(3), np.zeros(2), TICK)
