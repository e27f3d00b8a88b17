"""The twins' compiled loops give the numpy/scipy code's results bit for bit (tvsd.sim.twin_kernels)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.signal import sosfilt, sosfilt_zi

from tvsd.sim.mpu6050 import dlpf_sos
from tvsd.sim.twin_kernels import dlpf_counts, leaky_rate


@pytest.mark.parametrize("dlpf_cfg", [0, 1, 3, 6])
def test_dlpf_counts_is_sosfilt_then_the_adc_bit_for_bit(dlpf_cfg: int) -> None:
    rng = np.random.default_rng(dlpf_cfg)
    sos = dlpf_sos(dlpf_cfg, 1027.0)
    lsb = np.array([6e-4] * 3 + [1.3e-4] * 3)
    offset = rng.uniform(-900, 900, 6)
    x = rng.normal(0, 3, (400, 6))
    x[50:60] *= 300  # past int16's range: clipped
    zi0 = sosfilt_zi(sos)[:, :, None] * x[0][None, None, :]
    zi = zi0.copy()
    got = np.concatenate([dlpf_counts(sos, zi, x[a:b].copy(), lsb, offset) for a, b in ((0, 7), (7, 400))])
    y, zi_ref = sosfilt(sos, x, axis=0, zi=zi0)
    want = np.clip(np.rint(y / lsb + offset), -32768, 32767).astype(np.int64)
    assert np.array_equal(got, want) and np.array_equal(zi, zi_ref)
    assert (got == 32767).any() or (got == -32768).any()


def _leaky_rate_python(s, ends, accel, stop, tau, omega, pos):  # the loop it replaced
    rate = np.empty(s.size)
    k, last = 0, ends.size - 1
    for i, si in enumerate(s.tolist()):
        while pos < si:
            while k < last and ends[k] <= pos:
                k += 1
            end = ends[k] if ends[k] > pos else stop if pos < stop else math.inf
            nxt = min(si, end)
            a = accel[k] if pos < stop else 0.0
            c = math.exp(-(nxt - pos) / tau)
            omega = c * omega + tau * (1.0 - c) * a
            pos = nxt
        rate[i] = omega
    return rate, pos, omega


def test_leaky_rate_is_the_python_loop_bit_for_bit() -> None:
    rng = np.random.default_rng(1)
    ends = 0.001 * np.arange(1, 41)  # 1 ms chunks
    accel = rng.normal(0, 2, ends.size)
    stop = float(ends[-1] + 0.01)
    # samples inside, on chunk edges, past the ring's end, past the hold (no acceleration)
    s = np.sort(np.concatenate([rng.uniform(0, 0.06, 50), ends[:5], [0.045, 0.0555]]))
    got = leaky_rate(s, ends, accel, stop, 1.0, 0.2, 0.0)
    want = _leaky_rate_python(s, ends, accel, stop, 1.0, 0.2, 0.0)
    assert np.array_equal(got[0], want[0]) and got[1:] == want[1:]
