"""The encoder's quantisation in the residual: a known spectral floor, not a fitted shape.

When the recorded speed is an encoder's backward difference, ω[k] = (φ[k] − φ[k−1])·fs with φ a
whole number of counts of q = 2π/N rad, ω lies on a grid of step s = q·fs, and its error is
fs·(e[k] − e[k−1]) with e the angle's quantisation error. At a local rate of p counts per sample
(speed |ω|/s) the count crossed in a sample is ⌊p⌋ or ⌈p⌉, so var(fs·Δe) = s²·{p}(1 − {p})
({p}: the fractional part) — s²/6, the white-e value q²/12 differenced, when {p} is spread over
[0, 1), less at a fraction of a count per sample (a shaft that moves one count in ten samples
has s²·0.09). Its spectrum, for e white, is var·4·sin²(πf/fs)/fs; the doctor's acceleration rows
take it through the band filter (filtfilt: |B|⁴), the central difference (fs·sin(2πf/fs))², the
decimation's anti-alias filter (|C|⁴) and the decimation's aliases: f⁴ at low frequency.

The level comes from the count step and the recorded speed only: no free parameter. The step is
the declared `# encoder_counts_per_rev:` N when ω lies on its grid (s = 2π/N·fs), else the grid
ω is seen to lie on (a count difference whatever the header says); a speed that is not on a grid
(a tachometer, tvsd's own period-mean speed with its measurement noise) has no floor: its φ's
quantisation never reaches the residual, which is built from ω.

Where e is not white: at a constant speed the error is a sawtooth, its spectrum lines at the
count rate's fractional part × fs and harmonics, aliased. The speed's own variation over a
spectral segment (vibration, excitation) spreads them by n·δω/q Hz for harmonic n: at 8192
counts/rev hundreds of hertz (white in the band), at 256 counts/rev tens, so there the floor is
the lines' mean level, not their shape (docs/measurements/quantfloor.md).

The rows the doctor leaves out (the shaft stuck) are gaps in the residual; with this floor their
edges are ramped (`gated`), else they leak its f⁴ power into the lowest bins
(docs/measurements/quantlow.md).

A speed interpolated between an encoder's frames (`tvsctl export`: φ at each sample's end read off
the line between the frames that bracket it, ω its difference over the sample) is off the count
grid, yet carries the count's error: the frames' angles are whole counts, so at each sample edge
the angle's error is ε_k = (1 − a_k)·e_j + a_k·e_{j+1}, e the frames' errors (white, q²/12, where the
shaft crosses many counts per frame), a_k the edge's place between frames j and j+1. The export
declares the frames' rate and offset against the edges (`# encoder_frame_hz:`,
`# encoder_frame_offset_s:`) and the counts; `interpolation_gain` turns them into ε's spectrum
relative to a white error at the samples (1 at every frequency for an on-grid count difference):
frames at twice the sample rate at a fixed offset give a white ε of variance (1 − a)² + a² (0.5–1);
frames at the sample rate, shared by neighbouring edges, a low-pass one. ω's error is then
fs·(ε_k − ε_{k−1}), through the same rows' filters as the on-grid floor
(docs/measurements/closedcolour2.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.signal import butter, filtfilt, freqz

from tvsd.analysis.command_levels import without_levels
from tvsd.analysis.count_grid import STEP_KEY, recorded_step
from tvsd.analysis.prep import Prepared, antialias

SEGMENT_S = 4.0  # tvsd.analysis.noise's Welch segment (noise imports this module)

Floor = Callable[[np.ndarray], np.ndarray]


HARMONICS = 64  # sawtooth harmonics placed by the speed; the rest (1/64 of e's power) spread flat
SPEED_HZ = 5.0  # the speed that places the lines: ω low-passed here (its own quantisation noise,
# ∝ f_c^1.5, then moves a line by < 1 count/s at 1 kHz, less than a 0.05 rad/s^1.5 vibration's wander)
OVERSAMPLE = 16  # the lines' histogram is this much finer than the Welch resolution


def error_psd(speed: np.ndarray, weight: np.ndarray, q: float, fs: float, segment_s: float) -> Floor:
    """One-sided PSD of the angle's quantisation error e over the samples' weights (their mean
    over the record, as a Welch average sees it), at full-rate frequencies in [0, fs/2].

    At a count rate r = |ω|/q (counts/s) e is a sawtooth: harmonic n at n·r folded into [0, fs/2],
    of power q²/(2π²n²) (Σ = q²/12). The record's spectrum is the lines' histogram over its samples
    (slow changes of r: the instantaneous-frequency spectrum), seen through the Welch segment's
    Hann window. A speed spread over many counts per sample fills it evenly: white, q²/(6·fs)."""
    df = 1.0 / segment_s / OVERSAMPLE
    nbins = int(fs / 2 / df) + 1
    rate = np.abs(speed) / q
    hist = np.zeros(nbins)
    w = weight / max(len(weight), 1)
    for n in range(1, HARMONICS + 1):
        f = np.mod(n * rate, fs)
        f = np.where(f > fs / 2, fs - f, f)
        line = q * q / (2 * math.pi**2 * n * n)  # harmonic n of a sawtooth of height q
        hist += np.bincount(np.minimum((f / df + 0.5).astype(int), nbins - 1), w, nbins) * line
    rest = q * q / (2 * math.pi**2) * (math.pi**2 / 6 - sum(1.0 / k**2 for k in range(1, HARMONICS + 1)))
    density = hist / df + float(np.sum(w)) * rest / (fs / 2)
    m = 256  # the Hann window's spectral kernel at the histogram's resolution
    kern = np.abs(np.fft.rfft(np.hanning(m), OVERSAMPLE * m)) ** 2
    half = 3 * OVERSAMPLE  # the mainlobe and first sidelobes (±3 Welch bins)
    kernel = np.concatenate([kern[1 : half + 1][::-1], kern[: half + 1]])
    kernel /= kernel.sum()
    smooth = np.convolve(np.pad(density, half, mode="reflect"), kernel, mode="valid")
    grid = np.arange(nbins) * df

    def psd(f: np.ndarray) -> np.ndarray:
        return np.asarray(np.interp(f, grid, smooth))

    return psd


def _gain(prep: Prepared, f: np.ndarray) -> np.ndarray:
    """|transfer|² from the recorded speed to the acceleration rows at full-rate frequencies f:
    band filter and anti-alias filter both run forward and back (|·|⁴), the central difference."""
    fs = prep.data.sample_rate_hz
    w = 2 * np.pi * f / fs
    _, hb = freqz(prep.b, prep.a, worN=w)
    g = np.abs(hb) ** 4 * (fs * np.sin(w)) ** 2
    if prep.band.decim > 1:
        bc, ac = antialias(prep.band.decim)
        _, hc = freqz(bc, ac, worN=w)
        g = g * np.abs(hc) ** 4
    return np.asarray(g)


def count_step(prep: Prepared) -> float | None:
    """The recorded speed's count step, None when it is not a rotary count difference."""
    d = prep.data
    if d.speed is None or d.units.axis != "rotary":
        return None
    if STEP_KEY in d.meta:  # re-timed: the step was read on the samples as recorded
        return float(d.meta[STEP_KEY])
    return recorded_step(d.speed, d.sample_rate_hz, d.meta)


FRAME_HZ_KEY = "encoder_frame_hz"  # the frames' rate, Hz (tvsctl export)
FRAME_OFFSET_KEY = "encoder_frame_offset_s"  # the frames' offset after the sample edges, s


def frames(prep: Prepared) -> tuple[float, float, float] | None:
    """(q rad, frame rate Hz, offset s) of a speed interpolated between an encoder's frames: the
    counts and the frames' timing declared, and ω not itself a count difference; else None."""
    d = prep.data
    keys = ("encoder_counts_per_rev", FRAME_HZ_KEY, FRAME_OFFSET_KEY)
    if d.speed is None or d.units.axis != "rotary" or not all(k in d.meta for k in keys):
        return None
    if count_step(prep) is not None:
        return None
    try:
        counts, rate, offset = (float(d.meta[k]) for k in keys)
    except ValueError:
        return None
    if not (counts >= 1 and math.isfinite(rate) and rate > 0 and math.isfinite(offset)):
        return None
    return 2 * math.pi / counts, rate, offset


def interpolation_gain(fs: float, frame_hz: float, offset_s: float, n: int = 8192) -> Floor:
    """ε's two-sided PSD at the samples over a white error's of the same variance at the samples
    (the on-grid count difference's e), as a function of frequency: ε_k = (1 − a_k)·e_j + a_k·e_{j+1}
    at edge k = 0, 1, … (time k/fs; frame j at offset_s + j/frame_hz), e white. Its autocovariance
    R(ℓ) = (1/n)·Σ_k Σ_j W[k, j]·W[k+ℓ, j] (W the interpolation's weights), over n edges, so a rate
    a little off a multiple of fs drifts the a_k over them as it does over the record. Divided by n,
    not by the n − ℓ pairs: the weights' periodogram, never negative (with frames slower than the
    samples the lags reach n, and the per-pair mean gave a negative floor, NaN in the colour test)."""
    x = (np.arange(n) / fs - offset_s) * frame_hz
    j = np.floor(x)
    a = x - j
    # Beyond 2·fs/frame_hz + 1 no two edges share a frame; nor is a lag past the n edges averaged
    # (frames slower than that: a declared 1e-9 Hz asked for 7 TiB).
    lags = min(math.ceil(2 * fs / frame_hz) + 1, n - 1)
    r = np.zeros(lags + 1)
    for lag in range(lags + 1):
        j0, a0, j1, a1 = j[: n - lag], a[: n - lag], j[lag:], a[lag:]
        both = (1 - a0) * ((j1 == j0) * (1 - a1) + (j1 + 1 == j0) * a1)
        both += a0 * ((j1 == j0 + 1) * (1 - a1) + (j1 == j0) * a1)
        r[lag] = float(np.sum(both)) / n

    def gain(f: np.ndarray) -> np.ndarray:
        w = 2 * np.pi * np.asarray(f, dtype=float) / fs
        g = r[0] + 2 * sum(r[m] * np.cos(m * w) for m in range(1, len(r)))
        return np.maximum(g, 0.0)  # ≥ 0 but for the cosine sum's rounding (1e-11 at 8192 lags)

    return gain


def floor(prep: Prepared, keep: np.ndarray) -> Floor | None:
    """The quantisation's one-sided PSD in the residual rows, as a function of the rows'
    frequency; None when ω is neither a count difference nor interpolated between declared
    frames. `keep`: each row's weight in the residual the spectral tests see, as power (0 outside
    the rows kept, 1 inside; `gated`'s ramps squared)."""
    d = prep.data
    step = count_step(prep)
    framed = frames(prep) if step is None else None
    if (step is None and framed is None) or d.speed is None:
        return None
    fs = d.sample_rate_hz
    b, a = butter(2, SPEED_HZ / (fs / 2))
    speed = filtfilt(b, a, d.speed)
    weight = np.zeros(len(speed))  # full-rate samples of the rows kept (each row stands for decim)
    rows_at = prep.trim + prep.band.decim * np.arange(len(keep))
    for j in range(prep.band.decim):
        idx = np.clip(rows_at + j - prep.band.decim // 2, 0, len(speed) - 1)
        weight[idx] = np.where(keep > 0, keep, weight[idx])
    weight *= len(speed) / max(prep.band.decim * len(keep), 1)  # the mean over the rows, not the record
    if step is not None:
        s_e = error_psd(speed, weight, step / fs, fs, SEGMENT_S)
    else:  # e white at the frames (q²/12), through the interpolation: q²/(6·fs)·gain one-sided
        assert framed is not None
        q, frame_hz, offset = framed
        level = float(np.mean(weight)) * q * q / (6 * fs)
        spread = interpolation_gain(fs, frame_hz, offset)
        s_e = lambda f: level * spread(f)  # noqa: E731
    rows_rate = fs / prep.band.decim

    def psd(f: np.ndarray) -> np.ndarray:
        f = np.asarray(f, dtype=float)
        total = np.zeros_like(f)
        for k in range(prep.band.decim + 1):  # the aliases k·fr ± f folded into [0, fs/2]
            for fa in (k * rows_rate - f, k * rows_rate + f) if k else (f,):
                ok = (fa >= 0) & (fa <= fs / 2)
                fa_ok = np.where(ok, fa, 0.0)
                s = s_e(fa_ok) * (fs * 2 * np.sin(np.pi * fa_ok / fs)) ** 2 * _gain(prep, fa_ok)
                total += np.where(ok, s, 0.0)
        return total

    return psd


EDGE_TAPER_S = 0.1  # the ramp into and out of each stretch of rows kept (see `gated`)


def edge_taper(keep: np.ndarray, rate_hz: float, seconds: float = EDGE_TAPER_S) -> np.ndarray:
    """Weights of the rows: 0 outside `keep`, rising as sin² over `seconds` from each row left out
    to 1 (the record's own ends are not edges: the Welch segment's window tapers them)."""
    i = np.arange(len(keep))
    far = len(keep) + int(seconds * rate_hz) + 1
    last_out = np.maximum.accumulate(np.where(keep, -far, i))
    next_out = np.minimum.accumulate(np.where(keep, len(keep) + far, i)[::-1])[::-1]
    dist = np.minimum(i - last_out, next_out - i)
    ramp = np.sin(0.5 * np.pi * np.minimum(dist / max(seconds * rate_hz, 1e-9), 1.0)) ** 2
    return np.asarray(np.where(keep, ramp, 0.0))


def gated(
    prep: Prepared,
    keep: np.ndarray,
    residual: np.ndarray,
    rate_hz: float,
    model: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, Floor | None]:
    """The residual rows the spectral tests see, and the quantisation's floor in them.

    Rows left out (the shaft stuck) are zeros. With a count-difference speed, a hard edge there
    multiplies the residual by a step, whose 1/ν² sidelobes carry the quantisation's f⁴ power
    from the band's top (10⁴–10⁵× its in-band level) into the lowest bins: on the outsider's
    256-count nulls 3·10⁵× the floor at 0.5–1 Hz, the whole low end of the residual, and
    `colored_noise` (docs/measurements/quantlow.md). Nor is that leak the stationary floor seen
    through the gaps: the speed is lowest at a gap's edge, its quantisation a pulse train, and
    the leak computed from the rows' mean floor left 5 of 200 gapped family nulls coloured.
    So each stretch of rows is ramped in and out (sin² over EDGE_TAPER_S: sidelobes ∝ 1/ν³,
    the leak from 50–100 Hz down by (ν·T)⁴ ≈ 600–10⁴), and the floor follows the ramped rows
    (their weights squared). Without a floor (a tachometer, tvsd's own speed: no f⁴ term) the
    rows are not ramped. Either way, in open loop, what a constant per held command level
    explains is taken out first (tvsd.analysis.command_levels: a PWM's per-level error), refitted
    with the model's columns and whitening, `model` = (X, ar), when given."""
    # a static drive error per held command level (a PWM's resolution) is not the vibration's colour
    resid = np.where(keep, without_levels(prep, keep, residual, *(model or (None, None))), 0.0)
    if count_step(prep) is None and frames(prep) is None:
        return resid, None
    w = edge_taper(keep, rate_hz)
    return w * resid, floor(prep, w * w)
