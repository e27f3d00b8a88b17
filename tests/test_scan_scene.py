"""SIL acceptance of the scan pipeline: the paper's Design of Experiment B against ground truth.

One full DoE B (3 σv × 3 speeds × 9 targets, with and without compensation, 10 s each) runs once
for the module (≈ 5 s).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tvsd.causes import parse_effects
from tvsd.config import load_config
from tvsd.errors import UsageError
from tvsd.scan.geometry import aim, doe_b_target
from tvsd.scan.pipeline import process
from tvsd.scan.pulses import clean
from tvsd.scan.settings import ScanSettings
from tvsd.scan.stream import PointStream
from tvsd.sim import scan_report as report
from tvsd.sim import scene

IMBALANCE = parse_effects(["imbalance:amplitude=7e-5,phase=0.3"])


@pytest.fixture(scope="module")
def doe():
    cases, clouds = scene.doe_b(load_config(), ScanSettings(), IMBALANCE, seconds=10.0)
    return cases, clouds


def test_every_case_is_run_with_enough_points(doe):
    cases, _ = doe
    ours = [c for c in cases if c.method == "centred"]
    assert len(ours) == 3 * 3 * 9 * 2
    # 10 s at 15 rev/s is 150 revolutions; the first and last cannot be centred.
    assert min(c.n_points for c in ours) >= 145


def test_reported_sigma_is_honest_in_every_case(doe):
    cases, _ = doe
    for c in cases:
        if c.method != "centred":
            continue
        # Acceptance: ±2σ covers ≥ 90 % of the points. A Gaussian with the right σ covers 95.4 %;
        # with ≥ 145 points the sampling std of the share is ≤ 1.8 %, so 90 % is a 3σ floor.
        assert c.coverage_2sigma >= 0.90, c
    # Honest also means not inflated: over all cases the reported σx is within 25 % of the
    # measured error std (the no-compensation σ at the lowest vibration covers the imbalance's
    # bias too, which the std leaves out).
    ratio = [c.reported_sigma_mm[0] / c.err_std_mm[0] for c in cases if c.method == "centred"]
    assert 0.8 < float(np.median(ratio)) < 1.25


def test_encoder_sigma_is_honest_at_the_doe_speeds(doe):
    cases, _ = doe
    enc = [c for c in cases if c.method == "encoder"]
    assert len(enc) == 81
    # Measured 0.94–0.98 per case; 0.90 is 3 sampling std (~1.7 % at ~150 points) below 95 %.
    assert min(c.coverage_2sigma for c in enc) >= 0.90
    # In strong vibration an 8192-count encoder read at 10 kHz (quantisation-limited, ~0.4 mm)
    # beats the zero-pulse fit without IMU (~6 mm) by an order; at σv = 0.0838 they are alike.
    for sv in (0.8069,):
        e = np.mean([c.err_std_mm[0] for c in enc if c.sigma_v == sv])
        fit = np.mean(
            [
                c.err_std_mm[0]
                for c in cases
                if c.sigma_v == sv and c.method == "centred" and not c.compensated
            ]
        )
        assert e < fit / 5


def test_compensation_gains_at_least_2x_in_the_strongest_vibration(doe):
    cases, _ = doe
    pooled, worst = report.compensation_gain(cases, 0.8069)
    assert worst >= 2.0 and pooled >= 2.0, (pooled, worst)


def test_naive_reading_is_worse_than_the_quadratic_fit(doe):
    cases, _ = doe
    rows = report.table4(cases, 0.8069, 20.0)
    for r in rows:
        assert r["uncompensated_mm"][0] < r["naive_mm"][0]
        assert r["compensated_mm"][0] < r["uncompensated_mm"][0] / 2
        # MODEL-NOTES §6: z ≡ 0 at γ = 0 whatever the error, and y does not depend on γ.
        if r["gamma_deg"] == 0.0:
            assert r["naive_mm"][2] == 0.0
    assert rows[0]["naive_mm"][1] == pytest.approx(rows[1]["naive_mm"][1], rel=1e-9)


def test_vibration_flag_follows_the_threshold(doe):
    cases, _ = doe
    for c in cases:
        # Measured √q ≈ σv (plus the imbalance's 0.02 rad/s^1.5 share); threshold 0.3381.
        if c.sigma_v == 0.8069:
            assert c.flagged_share == 1.0
        elif c.sigma_v == 0.0838:
            assert c.flagged_share == 0.0


def test_stream_gives_the_batch_points():
    cfg = load_config()
    trace, t_start = scene.spin_trace(cfg, 20.0, 0.8069, IMBALANCE, 2.0, seed=5)
    for estimator in ("centred", "causal"):
        settings = ScanSettings(estimator=estimator)
        aimed = aim(*doe_b_target(60.0, 15.0, 2.0, settings.baseline_m), settings)
        rec = scene.record(
            trace, aimed.beta, settings, scene.drive_model(cfg), t_start, np.random.default_rng(2)
        )
        batch = process(
            clean(rec.kind, rec.ticks, rec.tick_s), aimed.phi, aimed.gamma, settings, rec.known
        ).cloud
        stream = PointStream(settings, aimed.phi, aimed.gamma, rec.tick_s, damping=rec.known.damping)
        k = rec.known
        out = []
        sample_end = k.t0 + (np.arange(len(k.imu)) + 1) * k.dt
        fed = 0
        for kind, tick in zip(rec.kind, rec.ticks, strict=True):
            upto = int(np.searchsorted(sample_end, tick * rec.tick_s)) + 1  # FIFO a sample ahead
            out += stream.add_samples(k.t0 + fed * k.dt, k.imu[fed:upto], k.drive[fed:upto])
            fed = max(fed, upto)
            out += stream.add_pulse(int(kind), int(tick))
        got = {round(p.t, 7): p for p in out}
        # The stream's first points lack a full σ window; compare where both have one.
        common = [i for i, t in enumerate(batch.t) if round(float(t), 7) in got and t > batch.t[0] + 0.6]
        assert len(common) > 20, estimator
        for i in common:
            p = got[round(float(batch.t[i]), 7)]
            # Same data; only the known acceleration's state differs: the stream's buffer starts at
            # rest with its own mean, and through the drive's damping (λ = 0.41 1/s) that leaves a
            # slow exponential the quadratic fit absorbs all but ~λ²·δω·T³/6 of (≲ 1e-6 rad for
            # δω ~ 0.5 rad/s over T = 0.1 s): a few % of the point's σβ (~4e-5 rad) at most.
            assert abs(p.beta - batch.beta[i]) < 0.05 * batch.sigma_beta[i]
            # σ sees the same state through λ·ω_K in the damped acceleration: ≲ 0.2 % measured.
            assert p.sigma_beta == pytest.approx(batch.sigma_beta[i], rel=1e-2)


def test_scene_refuses_a_shaft_that_does_not_turn():
    t = np.linspace(0, 1, 11)
    with pytest.raises(UsageError, match="does not turn steadily forward"):
        scene.pulse_times(t, np.zeros(11), 1.0, 0.0)


def test_crossings_are_where_the_angle_reaches_the_level():
    t = np.linspace(0.0, 1.0, 10001)
    phi = 40.0 * t + 3.0 * t * t
    levels = np.array([2 * math.pi, 4 * math.pi + 1.0])
    got = scene.crossing_times(t, phi, levels)
    exact = (-40.0 + np.sqrt(1600.0 + 12.0 * levels)) / 6.0
    # Linear interpolation inside a 1e-4 s step: error ≤ φ''·dt²/8/φ' = 6·1e-8/8/40 ≈ 2e-10 s.
    np.testing.assert_allclose(got, exact, atol=1e-9)


def test_without_imu_points_are_flagged_and_sigma_is_the_right_size():
    from tvsd.scan.points import FLAG_NO_IMU, FLAG_VIBRATION

    cfg = load_config()
    trace, t_start = scene.spin_trace(cfg, 25.0, 0.8069, IMBALANCE, 6.0, seed=9)
    settings = ScanSettings()
    aimed = aim(*doe_b_target(60.0, 0.0, 2.0, settings.baseline_m), settings)
    rec = scene.record(trace, aimed.beta, settings, scene.drive_model(cfg), t_start, np.random.default_rng(3))
    cloud = process(clean(rec.kind, rec.ticks, rec.tick_s), aimed.phi, aimed.gamma, settings, None).cloud
    assert np.all(cloud.flags & FLAG_NO_IMU) and not np.any(cloud.flags & FLAG_VIBRATION)
    ok = np.isfinite(cloud.sigma_beta)
    assert ok.mean() > 0.9  # the first revolutions have no pulse history yet
    err = cloud.beta[ok] - aimed.beta
    # From the zero pulses alone σ is low by up to 1.5× at 15 rev/s (uncertainty.pulse_intensity);
    # at 25 rev/s it was measured within 10 %: the ratio must stay inside [0.7, 1.4].
    assert 0.7 < np.std(err) / np.sqrt(np.mean(cloud.sigma_beta[ok] ** 2)) < 1.4


def test_sigma_carries_the_acceleration_inside_imu_samples_at_25_rps():
    """With the gyro-scale, drive-model and clock errors off in the scene and in the budget, what the
    compensated β still misses at 25 rev/s is mostly the acceleration inside each 1 ms IMU sample
    (~2.3e-5 rad at σv = 0.8069, against the 62.5 ns timer's ~4e-6 rad and the gyro's ~6e-6 rad):
    σβ must carry it. Without it σβ is ~7e-6 rad, 3× too small."""
    import dataclasses

    cfg = load_config()
    trace, t_start = scene.spin_trace(cfg, 25.0, 0.8069, IMBALANCE, 6.0, seed=11)
    settings = dataclasses.replace(
        ScanSettings(), imu_scale_tolerance=0.0, model_tolerance=0.0, clock_sync_error_s=0.0
    )
    sensors = scene.SilSensors(imu_scale_error=0.0, model_error=0.0, clock_sync_error_s=0.0)
    rng = np.random.default_rng(4)
    err, var = [], []
    for phi in (40.0, 60.0, 80.0):
        aimed = aim(*doe_b_target(phi, 0.0, 2.0, settings.baseline_m), settings)
        rec = scene.record(trace, aimed.beta, settings, scene.drive_model(cfg), t_start, rng, sensors=sensors)
        cloud = process(
            clean(rec.kind, rec.ticks, rec.tick_s), aimed.phi, aimed.gamma, settings, rec.known
        ).cloud
        err.append(cloud.beta - aimed.beta)
        var.append(cloud.sigma_beta**2)
    ratio = math.sqrt(np.mean(np.concatenate(err) ** 2) / np.mean(np.concatenate(var)))
    # ~450 points over one vibration realisation: the rms has a few % sampling spread; measured
    # 0.96–1.05 over seeds 11–15.
    assert 0.85 < ratio < 1.15, ratio


def test_stream_emits_each_point_once_the_imu_passes_its_own_next_zero_pulse():
    """IMU batches every 38 ms, 20 ms behind the pulses (a 20 ms FIFO poll plus the filter's
    delay): a point waits for its next zero pulse (≤ a turn, 50 ms at 20 rev/s) and the batch that
    passes it (≤ 38 + 20 ms). Judged by the newest zero pulse instead, the batch
    period and the turn beat and points waited up to 10 turns (430 ms in the daemon)."""
    cfg = load_config()
    trace, t_start = scene.spin_trace(cfg, 20.0, 0.8069, IMBALANCE, 2.0, seed=5)
    settings = ScanSettings()
    aimed = aim(*doe_b_target(60.0, 15.0, 2.0, settings.baseline_m), settings)
    rec = scene.record(trace, aimed.beta, settings, scene.drive_model(cfg), t_start, np.random.default_rng(2))
    stream = PointStream(settings, aimed.phi, aimed.gamma, rec.tick_s, damping=rec.known.damping)
    k = rec.known
    fed, next_batch, delays = 0, k.t0, []
    for kind, tick in zip(rec.kind, rec.ticks, strict=True):
        now = tick * rec.tick_s
        out = []
        if now >= next_batch:
            upto = int((now - 0.020 - k.t0) / k.dt)
            if upto > fed:
                out += stream.add_samples(k.t0 + fed * k.dt, k.imu[fed:upto], k.drive[fed:upto])
                fed = upto
            next_batch += 0.038
        out += stream.add_pulse(int(kind), int(tick))
        delays += [now - p.t for p in out]
    assert len(delays) > 20
    # next zero ≤ 50 ms, then the batch covering it: 20 ms + a 1 ms cell behind, every 38 ms, taken
    # at the first pulse after its time (pulses every ~25 ms here): 134 ms; measured 100 ms.
    assert max(delays) < 0.050 + 0.021 + 0.038 + 0.025
