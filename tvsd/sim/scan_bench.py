"""Benchmarks of the scan pipeline (for `tvsctl bench` and README's Benchmarks table)."""

from __future__ import annotations

import math
import time

import numpy as np

from tvsd.scan.geometry import jacobian_beta, triangulate


def bench_triangulation(n: int = 1_000_000, repeats: int = 3) -> dict[str, float]:
    """Points/s of eqs. (1)–(3) with their Jacobian (what every point costs), best of `repeats`."""
    rng = np.random.default_rng(0)
    phi = rng.uniform(0.7, 1.4, n)
    beta = rng.uniform(1.4, 2.2, n)
    gamma = rng.uniform(-0.26, 0.26, n)
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        triangulate(phi, beta, gamma, 0.5)
        jacobian_beta(phi, beta, gamma, 0.5)
        best = min(best, time.perf_counter() - t0)
    return {"scan_triangulation_points_per_s": n / best}


def bench_pipeline(seconds: float = 20.0, repeats: int = 3) -> dict[str, float]:
    """Points/s of the whole batch pipeline (pulse cleaning, compensated β, σ from the measured
    spectrum, triangulation) on a SIL recording at 25 rev/s, best of `repeats`."""
    from tvsd.causes import parse_effects
    from tvsd.config import load_config
    from tvsd.scan.geometry import aim, doe_b_target
    from tvsd.scan.pipeline import process
    from tvsd.scan.pulses import clean
    from tvsd.scan.settings import ScanSettings
    from tvsd.sim import scene

    cfg = load_config()
    settings = ScanSettings()
    effects = parse_effects(["imbalance:amplitude=7e-5,phase=0.3"])
    trace, t_start = scene.spin_trace(cfg, 25.0, 0.8069, effects, seconds, seed=7)
    aimed = aim(*doe_b_target(60.0, 15.0, 2.0, settings.baseline_m), settings)
    rec = scene.record(trace, aimed.beta, settings, scene.drive_model(cfg), t_start, np.random.default_rng(1))
    best, n = math.inf, 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        cloud = process(
            clean(rec.kind, rec.ticks, rec.tick_s), aimed.phi, aimed.gamma, settings, rec.known
        ).cloud
        best, n = min(best, time.perf_counter() - t0), len(cloud)
    return {"scan_pipeline_points_per_s": n / best}


def bench_latency(seconds: float = 3.0, rps: float = 20.0) -> dict[str, float]:
    """SIL: from optical pulse to point on the stream, centred and causal, with compensation.

    Reports the wait for the zero pulses the estimator needs (simulated time) and the compute time
    of the pulse that completes the point (wall time, p50 and p99) separately: the first is the
    method's, the second this machine's.
    """
    from tvsd.causes import parse_effects
    from tvsd.config import load_config
    from tvsd.scan.geometry import aim, doe_b_target
    from tvsd.scan.settings import ScanSettings
    from tvsd.scan.stream import PointStream
    from tvsd.sim import scene

    cfg = load_config()
    effects = parse_effects(["imbalance:amplitude=7e-5,phase=0.3"])
    trace, t_start = scene.spin_trace(cfg, rps, 0.8069, effects, seconds, seed=7)
    out: dict[str, float] = {}
    for estimator in ("centred", "causal"):
        settings = ScanSettings(estimator=estimator)
        aimed = aim(*doe_b_target(60.0, 15.0, 2.0, settings.baseline_m), settings)
        rec = scene.record(
            trace, aimed.beta, settings, scene.drive_model(cfg), t_start, np.random.default_rng(1)
        )
        stream = PointStream(settings, aimed.phi, aimed.gamma, rec.tick_s, damping=rec.known.damping)
        k = rec.known
        sample_end = k.t0 + (np.arange(len(k.imu)) + 1) * k.dt
        waits: list[float] = []
        compute: list[float] = []
        # Events in time order: each 1 ms sample arrives at its end, each pulse at its timestamp.
        pulse_t = rec.ticks * rec.tick_s
        events = sorted(
            [(float(te), 0, i) for i, te in enumerate(sample_end)]
            + [(float(tp), 1, i) for i, tp in enumerate(pulse_t)]
        )
        for t_now, what, i in events:
            t0 = time.perf_counter()
            if what == 0:
                points = stream.add_samples(k.t0 + i * k.dt, k.imu[i : i + 1], k.drive[i : i + 1])
            else:
                points = stream.add_pulse(int(rec.kind[i]), int(rec.ticks[i]))
            elapsed = time.perf_counter() - t0
            for p in points:
                waits.append(t_now - p.t)
                compute.append(elapsed)
        out[f"scan_latency_{estimator}_wait_ms"] = 1e3 * float(np.mean(waits))
        out[f"scan_latency_{estimator}_compute_p50_ms"] = 1e3 * float(np.percentile(compute, 50))
        out[f"scan_latency_{estimator}_compute_p99_ms"] = 1e3 * float(np.percentile(compute, 99))
    return out


def bench_stream(seconds: float = 4.0, rps: float = 25.0, batch: int = 20) -> dict[str, float]:
    """What the daemon's point stream holds the event loop for per SA batch (its IMU reader's
    batches of `batch` 1 ms samples), centred and compensated, on a SIL recording at 25 rev/s.

    Events go in in time order as the daemon sees them (a batch at the end of its last sample, each
    pulse at its timestamp); wall time per `add_samples` call: mean and p99 over all batches, and
    the mean over the batches that complete a point (the pipeline's work); the same in this
    thread's CPU time, which a loaded machine inflates less."""
    from tvsd.causes import parse_effects
    from tvsd.config import load_config
    from tvsd.scan.geometry import aim, doe_b_target
    from tvsd.scan.settings import ScanSettings
    from tvsd.scan.stream import PointStream
    from tvsd.sim import scene

    cfg = load_config()
    effects = parse_effects(["imbalance:amplitude=7e-5,phase=0.3"])
    trace, t_start = scene.spin_trace(cfg, rps, 0.8069, effects, seconds, seed=7)
    settings = ScanSettings()
    aimed = aim(*doe_b_target(60.0, 15.0, 2.0, settings.baseline_m), settings)
    rec = scene.record(trace, aimed.beta, settings, scene.drive_model(cfg), t_start, np.random.default_rng(1))
    k = rec.known
    stream = PointStream(settings, aimed.phi, aimed.gamma, rec.tick_s, damping=k.damping)
    events = sorted(
        [(k.t0 + (i + batch) * k.dt, 0, i) for i in range(0, len(k.imu) - batch + 1, batch)]
        + [(float(tp), 1, i) for i, tp in enumerate(rec.ticks * rec.tick_s)]
    )
    per_batch: list[tuple[float, float]] = []
    completing: list[tuple[float, float]] = []
    points = 0
    for _, what, i in events:
        if what == 1:
            points += len(stream.add_pulse(int(rec.kind[i]), int(rec.ticks[i])))
            continue
        t0, c0 = time.perf_counter(), time.thread_time()
        got = stream.add_samples(k.t0 + i * k.dt, k.imu[i : i + batch], k.drive[i : i + batch])
        elapsed, cpu = time.perf_counter() - t0, time.thread_time() - c0
        per_batch.append((elapsed, cpu))
        if got:
            completing.append((elapsed, cpu))
        points += len(got)
    ms, done = np.asarray(per_batch) * 1e3, np.asarray(completing) * 1e3
    return {
        "scan_stream_batch_ms_mean": float(ms[:, 0].mean()),
        "scan_stream_batch_ms_p99": float(np.percentile(ms[:, 0], 99)),
        "scan_stream_completing_batch_ms_mean": float(done[:, 0].mean()),
        # This thread's CPU time: what the stream costs even when the machine is shared
        "scan_stream_batch_cpu_ms_mean": float(ms[:, 1].mean()),
        "scan_stream_completing_batch_cpu_ms_mean": float(done[:, 1].mean()),
        "scan_stream_points": float(points),
    }
