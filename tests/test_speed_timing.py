"""timing.speed_lag's peak search by one inverse FFT gives the full scan's lag (docs/measurements/docmem.md).

The scan it replaces evaluated the cross-spectrum at every lag of a 0.05-sample grid over ±8
samples (321 lags × the band's bins: 125 MB per block of 32 lags on 1 h at 2 kHz, and most of
the CPU of the load). The new search evaluates that same grid only near the peaks of the
band-limited cross-correlation, so the answer is the scan's to its own resolution, 0.001 sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.signal import butter, filtfilt

from tvsd.analysis import timing

FINE_STEP = 0.001  # the fine grid's spacing: the resolution both searches claim


def _full_scan_lag(omega: np.ndarray, phi: np.ndarray, rate_hz: float) -> tuple[float, float]:
    """speed_lag as it was (integ3 8d9900c): the cross-spectrum at all 321 lags of the coarse grid."""
    n = len(omega)
    corner = min(timing.BAND_HZ, 0.4 * rate_hz)
    b, a = butter(4, corner / (rate_hz / 2))
    cut = n // 20
    w = filtfilt(b, a, omega)[cut : n - cut]
    wbar = filtfilt(b, a, timing.reference_speed(omega, phi, rate_hz))[cut : n - cut]
    f = np.fft.rfftfreq(len(w))
    keep = f <= 1.5 * corner / rate_hz
    cross = (np.fft.rfft(timing._detrended(w)) * np.conj(np.fft.rfft(timing._detrended(wbar))))[keep]
    fk = f[keep]

    def inner(grid: np.ndarray) -> np.ndarray:
        chunks = np.array_split(grid, len(grid) // 32 + 1)
        return np.real(np.concatenate([np.exp(2j * np.pi * np.outer(g, fk)) @ cross for g in chunks]))

    coarse = np.arange(-timing.MAX_LAG, timing.MAX_LAG + timing.GRID / 2, timing.GRID)
    best = float(coarse[int(np.argmax(inner(coarse)))])
    fine = best + np.linspace(-timing.GRID, timing.GRID, 101)
    lag = float(fine[int(np.argmax(inner(fine)))])
    before = float(np.sum((w - wbar)[timing.EDGE : -timing.EDGE] ** 2))
    left = float(np.sum((timing.retimed(w, lag) - wbar)[timing.EDGE : -timing.EDGE] ** 2))
    return lag, max(0.0, 1.0 - left / before)


def _late(omega: np.ndarray, samples: int) -> np.ndarray:
    return np.concatenate([np.full(samples, omega[0]), omega[: len(omega) - samples]]) if samples else omega


@pytest.fixture(scope="module")
def sil(tmp_path_factory: pytest.TempPathFactory) -> tuple[np.ndarray, np.ndarray]:
    from tvsd.config import load_config
    from tvsd.recording.csvfile import read
    from tvsd.sim.record import record

    path = Path(tmp_path_factory.mktemp("sil")) / "null.csv"
    record(load_config(), path, "steps", 20.0, (), seed=3)
    rec = read(path)
    return rec.omega, rec.phi


@pytest.mark.parametrize("samples", [0, 1, 3])
def test_sil_speed_made_late_gives_the_full_scans_lag(
    sil: tuple[np.ndarray, np.ndarray], samples: int
) -> None:
    omega, phi = sil
    late = _late(omega, samples)
    old, old_share = _full_scan_lag(late, phi, 1000.0)
    new, share = timing.speed_lag(late, phi, 1000.0)
    # The same grids are searched near the same peak: equal to the fine grid's step (the old
    # scan's own resolution), and the share is then the same function of the same lag.
    assert abs(new - old) <= FINE_STEP + 1e-12, (new, old)
    assert abs(share - old_share) <= 1e-3, (share, old_share)
    assert timing.off_reference(new, share) == timing.off_reference(old, old_share)


@pytest.mark.parametrize("rate_hz", [250.0, 500.0, 1000.0, 2000.0])
def test_tach_noise_gives_the_full_scans_lag(rate_hz: float) -> None:
    """A tach's in-band noise: a flat, many-peaked cross-correlation where the scan's best lag is
    wherever the noise puts it; the search must find the same lobe (at 250 Hz the kept band
    reaches Nyquist, the case the search's upsampling is for)."""
    rng = np.random.default_rng(5)
    n = int(20 * rate_hz)
    w = 100.0 + np.convolve(rng.standard_normal(n), np.ones(40) / 40, mode="same") * 60.0
    phi = np.cumsum(w) / rate_hz
    wbar = timing.reference_speed(w, phi, rate_hz)
    for trial in range(4):
        tach = wbar + np.convolve(rng.standard_normal(n), np.ones(3) / 3, mode="same") * (2.0 + trial)
        old, old_share = _full_scan_lag(tach, phi, rate_hz)
        new, share = timing.speed_lag(tach, phi, rate_hz)
        assert abs(new - old) <= FINE_STEP + 1e-12, (trial, new, old)
        assert abs(share - old_share) <= 1e-3
