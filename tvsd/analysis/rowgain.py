"""The rows' filters as a known power response: how far the peak test can see.

Every column of the inverse model goes through the band filter (filtfilt of a Butterworth:
|B|⁴ in power) and the decimation's anti-alias Chebyshev (filtfilt: |C|⁴) before it is a row
(tvsd.analysis.prep). The residual's noise — the vibration J·Δv and the differentiated speed
noise — enters through the acceleration column, the central difference of the filtered speed
(power (sin w / w)² against a true derivative, w = 2πf/fs; twice over when the speed is itself
the position's central difference). The commanded effort's [1, 2, 1]/4 average, cos⁴(w/2), is
the same average to within 7 % at the corner of a 1 kHz file; the residual's noise is the
acceleration's (checked on white noise through Prepared: docs/measurements/peakband.md).

The residual spectrum is G(f)·(the raw shape) + the quantisation floor (which has G in it
already, tvsd.analysis.quantisation._gain). The flat-to-1 % half corner that bounded the peak
test before (0.5·band_hz: 50 Hz of the ~100 Hz a 1 kHz file's rows carry) is then not needed:
the peak test runs to where G falls to PEAK_GAIN_MIN.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.signal import freqz

from tvsd.analysis.prep import Prepared, antialias

Gain = Callable[[np.ndarray], np.ndarray]

# The peak test's top: where G falls to ¼ — the filtfilt'd Butterworth's value at its corner
# (½ twice), i.e. the band filter's own band. Above it G falls as (f/fc)⁻¹⁶ and the Chebyshev's
# as ~(f/fc')⁻³², steep enough that the Hann window's leakage of lower bins and the aliases
# fold in more than the model's G (docs/measurements/peakband.md).
PEAK_GAIN_MIN = 0.25


def rows_gain(prep: Prepared) -> Gain:
    """G(f): the power response from a white acceleration (or effort) disturbance at the full
    rate to the residual rows, at the rows' frequencies f (Hz, below their Nyquist)."""
    fs = prep.data.sample_rate_hz
    differences = 1 if prep.data.speed is not None else 2
    b, a, decim = prep.b, prep.a, prep.band.decim

    def gain(f: np.ndarray) -> np.ndarray:
        f = np.asarray(f, dtype=float)
        w = 2 * np.pi * f / fs
        _, hb = freqz(b, a, worN=w)
        g = np.abs(hb) ** 4 * np.sinc(w / np.pi) ** (2 * differences)  # np.sinc(x) = sin(πx)/(πx)
        if decim > 1:
            bc, ac = antialias(decim)
            _, hc = freqz(bc, ac, worN=w)
            g = g * np.abs(hc) ** 4
        return np.asarray(g)

    return gain


def peak_top(gain: Gain, f: np.ndarray) -> float:
    """The highest of the spectrum's frequencies `f` up to which G stays ≥ PEAK_GAIN_MIN."""
    below = np.nonzero(gain(f) < PEAK_GAIN_MIN)[0]
    below = below[f[below] > 0]
    return float(f[below[0] - 1]) if len(below) and below[0] > 0 else float(f[-1])
