"""White noise through Prepared's own filtering against rowgain.rows_gain (docs/measurements/peakband.md).

A recording's Dataset with its columns replaced by noise: an integrated white acceleration as
the speed (the acceleration rows carry the residual's noise) and a white effort (the u path,
[1, 2, 1]/4). Prints, at a few frequencies, the measured rows' PSD over its low-band level
beside G(f), and the share of aliased power. Usage: peakband_gain_check.py CSV [seconds]"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
from scipy.signal import welch

from tvsd.analysis.dataset import load
from tvsd.analysis.prep import Band, prepare
from tvsd.analysis.rowgain import PEAK_GAIN_MIN, peak_top, rows_gain
from tvsd.config import load_config


def main() -> None:
    data = load(Path(sys.argv[1]), load_config(None))
    for fs in (500.0, 1000.0, 2000.0, 10000.0):
        seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 400.0
        n = int(seconds * fs)
        rng = np.random.default_rng(1)
        t = np.arange(n) / fs
        acc = rng.standard_normal(n)
        speed = np.cumsum(acc) / fs
        d = dataclasses.replace(
            data,
            t=t,
            u=rng.standard_normal(n),
            position=np.cumsum(speed) / fs,
            speed=speed,
            sample_rate_hz=fs,
            filled=None,
            refs={},
        )
        prep = prepare(d, Band())
        rate = fs / prep.band.decim
        g = rows_gain(prep)
        for name, rows in (("accel", prep.rows(prep.accel)), ("u", prep.band_rows(d.u))):
            f, p = welch(rows, fs=rate, nperseg=int(4 * rate))
            lo = (f > 0.5) & (f < 40)
            level = np.median(p[lo] / g(f[lo]))
            top = peak_top(g, f)
            print(f"fs {fs:g} {name}: rows {rate:g} Hz, G ≥ {PEAK_GAIN_MIN} to {top:.4g} Hz")
            for f0 in (50, 62, 75, 85, 95, 100, 105, 110):
                k = (f > f0 - 2) & (f < f0 + 2)
                if not k.any() or f0 >= rate / 2:
                    continue
                meas = float(np.mean(p[k])) / level
                model = float(np.mean(g(f[k])))
                print(f"   {f0:5g} Hz  measured {meas:.4f}  G {model:.4f}  ratio {meas / model:.4f}")


if __name__ == "__main__":
    main()
