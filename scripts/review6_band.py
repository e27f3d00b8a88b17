"""review6: the colour test on a white residual (a white acceleration through the rows' own
filters, tests/test_review6.py's `_white_rows`), six seeds per (rate, seconds): the colour band's
top and the colour p-values (docs/measurements/review6.md).

    nice -n 19 .venv/bin/python scripts/review6_band.py
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from test_review6 import _white_rows

from tvsd.analysis import noise

CASES = ((100.0, 120.0), (100.0, 600.0), (500.0, 120.0), (500.0, 600.0), (1000.0, 300.0))

if __name__ == "__main__":
    for fs, seconds in CASES:
        ps, top = [], 0.0
        for seed in range(6):
            rows, rate, cutoff = _white_rows(fs, seconds, seed)
            r = noise.analyse(rows, rate, 1.0, cutoff)
            ps.append(r.colour_p)
            top = r.colour_band_hz[1] if r.colour_band_hz else 0.0
        print(f"{fs:g} Hz {seconds:g} s  colour band top {top:.2f} Hz  p " + " ".join(f"{p:.2g}" for p in ps))
