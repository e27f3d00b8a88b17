"""Null distribution of the residual-spectrum peak statistic (tvsd.analysis.peak.PEAK_WHITE_LR).

Residuals shaped like the doctor's rows (a flat vibration plus differentiated measurement noise,
their mix drawn log-uniform over 1.5 decades each way), of the doctor's row rate (250 Hz) and a
recording's length; their Welch spectrum through noise.spectrum_report; one JSON line each:

    nice -n 5 .venv/bin/python scripts/naming_peak_null.py OUT.jsonl ROWS SEED COUNT
    (ROWS 7488: a 30 s recording; 14988: 60 s)
"""

from __future__ import annotations

import json
import sys

import numpy as np
from scipy.signal import welch

from tvsd.analysis.noise import SEGMENT_S, spectrum_report

RATE_HZ, BAND_HZ = 250.0, 100.0


def main() -> int:
    out, n, seed, count = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    rng = np.random.default_rng(seed)
    nper = int(SEGMENT_S * RATE_HZ)
    with open(out, "a") as f_out:
        for _ in range(count):
            mix = 10 ** rng.uniform(-1.5, 1.5)  # measurement share: flat-dominated … f²-dominated
            w = rng.standard_normal(n + 1)
            x = rng.standard_normal(n) + mix * np.diff(w) * RATE_HZ / (2 * np.pi * 30)
            f, p = welch(x, fs=RATE_HZ, nperseg=nper)
            r = spectrum_report(f, p, max(1, 2 * n // nper - 1), 1.0, BAND_HZ)
            row = {"n": n, "mix": mix, "lr_w": r.peak_white_lr, "lr_lp": r.peak_lr, "q": r.peak_q}
            f_out.write(json.dumps(row | {"f0": r.peak_hz, "col": r.colour_lr}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
