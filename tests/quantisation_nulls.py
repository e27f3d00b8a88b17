"""Residual rows of an encoder-difference speed with nothing hidden: for the colour test alone.

A shaft's speed ω = ω_det + ω_vib: a deterministic profile (staircase, multisine or smoothed
random steps) and the vibration, an Ornstein–Uhlenbeck speed whose acceleration is white
(σv rad/s^1.5, damped by the mechanical time constant τm). φ is the period integral of ω,
quantised to whole counts (q = 2π/N); the recorded speed is φ's backward difference × fs. The
rows go through the doctor's own chain (tvsd.analysis.prep: band filter, central difference,
parallel decimation), and the model part (ω̇_det − ω_vib/τm, what a fitted baseline leaves out of
the residual) is taken off exactly: what is left is the white vibration and the quantisation, a
null for the colour test without a fit (≈ 0.05 s per 30 s record instead of the doctor's 3 s).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import filtfilt, lfilter

from tvsd.analysis import quantisation
from tvsd.analysis.dataset import ROTARY, Dataset
from tvsd.analysis.design import STUCK_SHARE
from tvsd.analysis.prep import Band, Prepared, prepare

PROFILES = ("staircase", "multisine", "steps")


@dataclass(frozen=True)
class Null:
    counts: int
    fs: float
    profile: str
    top_counts_per_sample: float  # the profile's peak speed in counts per sample
    sigma_v: float
    seconds: float
    colour_tau_s: float = 0.0  # > 0: the vibration low-pass coloured (OU, τ) + a 0.3 white floor
    mode_hz: float = 0.0  # > 0: a structural mode's acceleration added to the vibration's
    mode_q: float = math.inf  # its Q (inf: a pure tone whose phase wanders, as the outsider's)
    mode_size: float = 0.0  # its amplitude in units of the noise: m·1.5·σv (tests/outsider_bench.py)


def draw(rng: np.random.Generator, seconds: float = 30.0, colour_tau_s: float = 0.0) -> Null:
    """Encoder 256–8192 counts/rev (log-uniform), 500–2000 Hz, peak speed 1–40 counts/sample."""
    counts = round(2 ** rng.uniform(8, 13))
    fs = float(rng.choice([500.0, 1000.0, 2000.0]))
    return Null(
        counts,
        fs,
        str(rng.choice(PROFILES)),
        float(10 ** rng.uniform(0, math.log10(40))),
        float(10 ** rng.uniform(math.log10(0.05), 0.0)),
        seconds,
        colour_tau_s,
    )


def _profile(rng: np.random.Generator, kind: str, n: int, fs: float, top: float) -> np.ndarray:
    t = np.arange(n) / fs
    if kind == "multisine":
        f = rng.uniform(0.1, 3.0, 5)
        w = np.sum(np.sin(2 * np.pi * f[:, None] * t + rng.uniform(0, 2 * np.pi, (5, 1))), axis=0)
        return top * w / np.max(np.abs(w))
    hold = rng.uniform(1.0, 3.0) if kind == "staircase" else rng.uniform(0.05, 0.3)
    levels = rng.uniform(-1.0, 1.0, int(t[-1] / hold) + 2) * top
    raw = levels[(t / hold).astype(int)]
    tau = rng.uniform(0.05, 0.3)  # the plant's response to each step: first order
    a = 1.0 / (1.0 + tau * fs)
    return np.asarray(lfilter([a], [1.0, a - 1.0], raw, zi=[raw[0] * (1 - a)])[0])


def with_mode(
    null: Null, rng: np.random.Generator, size: float, lo_hz: float = 30.0, hi_hz: float = 90.0
) -> Null:
    """The null with a structural mode drawn as the outsider bench draws one: a pure tone half the
    time, else Q log-uniform 31–208; its frequency uniform over [lo_hz, min(hi_hz, 0.2·fs)]."""
    q = math.inf if rng.random() < 0.5 else 80.0 * 2.6 ** rng.uniform(-1.0, 1.0)
    f0 = float(rng.uniform(lo_hz, min(hi_hz, 0.2 * null.fs)))
    return dataclasses.replace(null, mode_hz=f0, mode_q=q, mode_size=size)


def _mode(null: Null, rng: np.random.Generator, n: int) -> np.ndarray:
    """The mode's acceleration per sample, amplitude m·1.5·σv (its rms that over √2), as
    tests/outsider_bench.py makes its torque over J."""
    h = 1.0 / null.fs
    amp = null.mode_size * 1.5 * null.sigma_v
    if math.isinf(null.mode_q):  # a tone whose phase wanders (0.02 Hz line width)
        ph = np.cumsum(rng.standard_normal(n)) * math.sqrt(2 * math.pi * 0.02 * h)
        return np.asarray(amp * np.sin(2 * np.pi * null.mode_hz * np.arange(n) * h + ph))
    w0 = 2 * math.pi * null.mode_hz * h
    r = math.exp(-w0 / (2 * null.mode_q))
    x = lfilter([1.0], [1, -2 * r * math.cos(w0), r * r], rng.standard_normal(n))
    return np.asarray(amp * x / (x.std() * math.sqrt(2)))


def residual(
    null: Null, rng: np.random.Generator, gaps: bool = False
) -> tuple[np.ndarray, float, quantisation.Floor | None]:
    """The residual rows, their rate, and the quantisation floor the doctor would use. `gaps`:
    the rows where the shaft is (nearly) stuck left out, as the doctor leaves them out
    (tvsd.analysis.design's STUCK_SHARE), and the rest ramped in and out as the doctor does."""
    resid, keep, prep = rows(null, rng)
    rate = null.fs / prep.band.decim
    if not gaps:
        return resid, rate, quantisation.floor(prep, np.ones(len(resid), dtype=bool))
    gated, floor = quantisation.gated(prep, keep, resid, rate)
    return gated, rate, floor


def rows(
    null: Null, rng: np.random.Generator, band: Band | None = None
) -> tuple[np.ndarray, np.ndarray, Prepared]:
    """The residual rows (every row), the rows the doctor would keep (moving), and the prepared
    signals; `band`: the doctor's (None) or another (scripts/bandfloor_peaks.py's wider band)."""
    fs, n = null.fs, int(null.seconds * null.fs)
    q = 2 * math.pi / null.counts
    h = 1.0 / fs
    w_det = _profile(rng, null.profile, n, fs, null.top_counts_per_sample * q * fs)
    tau_m = 0.2
    decay = math.exp(-h / tau_m)
    kick = null.sigma_v * math.sqrt(h) * rng.standard_normal(n)
    if null.colour_tau_s > 0:  # as tests/outsider_bench.py colours it: OU of unit DC gain + 0.3 white
        d = math.exp(-h / null.colour_tau_s)
        white = 0.3 * null.sigma_v * math.sqrt(h) * rng.standard_normal(n)
        kick = lfilter([1.0 - d], [1.0, -d], kick) + white
    if null.mode_hz > 0:
        kick = kick + _mode(null, rng, n) * h
    w_vib = lfilter([1.0], [1.0, -decay], kick)
    w = w_det + w_vib
    phi = np.cumsum(w) * h  # φ[k] − φ[k−1] = ω[k]·h: ω is the period mean
    phi_m = np.floor(phi / q) * q
    w_meas = np.diff(np.concatenate([[0.0], phi_m])) * fs
    data = Dataset(
        "null", np.arange(n) * h, np.zeros(n), phi_m, w_meas, fs, 1.0, 0.0, ROTARY, False,
        meta={"encoder_counts_per_rev": str(null.counts)},
    )  # fmt: skip
    prep = prepare(data, band or Band())
    damping = (1.0 - decay) * fs  # the OU's pull, which the baseline's −c·ω column fits
    model = np.gradient(filtfilt(prep.b, prep.a, w_det), h) - damping * prep.lowpass(w_vib)
    resid = prep.rows(prep.accel - model)
    w = prep.rows(prep.speed)
    keep = np.abs(w) > STUCK_SHARE * float(np.max(np.abs(w)))
    return resid, keep, prep
