"""The incremental point stream (tvsd.scan.stream) gives the whole-window stream's points.

The reference is the stream as it was (tests/window_stream.py): the batch pipeline re-run over the
whole buffer — the last 12 zero pulses and 1 s of samples — at every computation. Both are fed
the same SIL recording in the daemon's order (20-sample SA batches at the end of their last sample,
each pulse at its timestamp), with the anomalies the pulse cleaning must sort out, for both
estimators, compensated and not.

Tolerances: t, β, x, y, z and the flags must be equal bit for bit (the same arithmetic on the same
values, row by row). σ and the vibration agree to a relative 1e-9: the σ model's FFTs are as long
as the widest row computed together, and the reference computed every row of its buffer at once,
so its sums round differently (~1e-15); any change of what the model sees (another window,
another mean) moves them by more than 1e-6.
"""

from __future__ import annotations

import numpy as np
import pytest
from window_stream import PointStream as WindowStream

from tvsd.causes import parse_effects
from tvsd.config import load_config
from tvsd.scan.geometry import aim, doe_b_target
from tvsd.scan.points import Point
from tvsd.scan.pulses import OPTICAL, ZERO
from tvsd.scan.settings import ScanSettings
from tvsd.scan.stream import PointStream
from tvsd.sim import scene

BATCH = 20  # samples per SA batch (the IMU reader's ~20 ms)
EXACT = ("t", "phi", "gamma", "beta", "x", "y", "z", "flags")
ROUNDED = ("sigma_x", "sigma_y", "sigma_z", "sigma_beta", "vibration")


@pytest.fixture(scope="module")
def trace():
    cfg = load_config()
    effects = parse_effects(["imbalance:amplitude=7e-5,phase=0.3"])
    return cfg, *scene.spin_trace(cfg, 25.0, 0.8069, effects, 2.5, seed=7)


def _spoil(kind: np.ndarray, ticks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A missed zero pulse, a doubled optical pulse, a doubled zero pulse, one out of order."""
    kind, ticks = list(kind), list(ticks)
    zeros = [i for i, k in enumerate(kind) if k == ZERO]
    opts = [i for i, k in enumerate(kind) if k == OPTICAL]
    del kind[zeros[20]], ticks[zeros[20]]
    opts = [i for i, k in enumerate(kind) if k == OPTICAL]
    zeros = [i for i, k in enumerate(kind) if k == ZERO]
    for at, k, dt in ((opts[30], OPTICAL, 2000), (zeros[40], ZERO, 500), (opts[50], OPTICAL, -(10**6))):
        kind.insert(at + 1, k)
        ticks.insert(at + 1, ticks[at] + dt)
    return np.asarray(kind), np.asarray(ticks, dtype=np.int64)


def _feed(stream: PointStream | WindowStream, rec: scene.Recording, kind, ticks) -> list[Point]:
    k = rec.known
    events = sorted(
        [(k.t0 + (i + BATCH) * k.dt, 0, i) for i in range(0, len(k.imu) - BATCH + 1, BATCH)]
        + [(float(t), 1, i) for i, t in enumerate(ticks * rec.tick_s)]
    )
    out: list[Point] = []
    for _, what, i in events:
        if what == 0:
            out += stream.add_samples(k.t0 + i * k.dt, k.imu[i : i + BATCH], k.drive[i : i + BATCH])
        else:
            out += stream.add_pulse(int(kind[i]), int(ticks[i]))
    return out


@pytest.mark.parametrize("estimator", ["centred", "causal"])
@pytest.mark.parametrize("compensate", [True, False])
@pytest.mark.parametrize("spoiled", [False, True])
def test_incremental_points_are_the_whole_window_points(trace, estimator, compensate, spoiled):
    cfg, tr, t_start = trace
    settings = ScanSettings(estimator=estimator)
    aimed = aim(*doe_b_target(60.0, 15.0, 2.0, settings.baseline_m), settings)
    rec = scene.record(tr, aimed.beta, settings, scene.drive_model(cfg), t_start, np.random.default_rng(1))
    kind, ticks = _spoil(rec.kind, rec.ticks) if spoiled else (rec.kind, rec.ticks)
    args = (settings, aimed.phi, aimed.gamma, rec.tick_s)
    opts = {"compensate": compensate, "damping": rec.known.damping}
    want = _feed(WindowStream(*args, **opts), rec, kind, ticks)
    got = _feed(PointStream(*args, **opts), rec, kind, ticks)
    assert len(want) > 40, "the recording must give points to compare"
    assert [p.t for p in got] == [p.t for p in want]
    for g, w in zip(got, want, strict=True):
        for f in EXACT:
            assert getattr(g, f) == getattr(w, f), (f, w.t)
        for f in ROUNDED:
            np.testing.assert_allclose(getattr(g, f), getattr(w, f), rtol=1e-9, err_msg=f"{f} at t={w.t}")
