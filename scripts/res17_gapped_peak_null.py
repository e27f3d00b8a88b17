"""The peak test's ratio on white nulls whole and with their first 40 % left out (zeros), SEED N
draws: median, 90/99 % points, how many pass PEAK_WHITE_LR (docs/measurements/res17.md §1).

    nice -n 19 .venv/bin/python scripts/res17_gapped_peak_null.py 1 100
"""

from __future__ import annotations

import sys

import numpy as np

from tvsd.analysis import noise
from tvsd.analysis.peak import PEAK_WHITE_LR


def main() -> int:
    rng = np.random.default_rng(int(sys.argv[1]))
    rate, n = 250.0, 7500
    out: dict[str, list[float]] = {"whole": [], "gapped": []}
    for _ in range(int(sys.argv[2])):
        x = rng.standard_normal(n)
        y = x.copy()
        y[: int(0.4 * n)] = 0.0
        out["whole"].append(noise.analyse(x, rate, 1.0, 100.0).peak_white_lr)
        out["gapped"].append(noise.analyse(y, rate, 1.0, 100.0).peak_white_lr)
    for k, v in out.items():
        a = np.array(v)
        print(
            f"{k}: median {np.median(a):.1f} q90 {np.quantile(a, 0.9):.1f} q99 {np.quantile(a, 0.99):.1f} "
            f"max {a.max():.1f}, > {PEAK_WHITE_LR:g}: {int(np.sum(a > PEAK_WHITE_LR))}/{len(a)}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
