"""How many moving encoder recordings the no-excitation check refuses (docs/measurements/review3.md).

    .venv/bin/python scripts/excite_encoder_refusals.py --seed 11 --nulls 400

Draws tests/quantisation_nulls.py's family (encoders of 256–8192 counts/rev, 500–2000 Hz, a
staircase, multisine or steps profile peaking at 1–40 counts per sample: every shaft turns),
20 s each, and runs tvsd.analysis.excitation.check_moving on the doctor's prepared rows with the
baseline's 8 columns. Prints the refusals with their 95 % Clopper–Pearson interval and each one's
encoder, rate, profile, median row speed and threshold.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import quantisation_nulls as qn

from tvsd.analysis import excitation
from tvsd.analysis.matrix import clopper_pearson
from tvsd.errors import DataFileError


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--nulls", type=int, default=400)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    refused = []
    for _ in range(a.nulls):
        null = qn.draw(rng, seconds=20.0)
        _, _, prep = qn.rows(null, rng)
        try:
            excitation.check_moving(prep, 8)
        except DataFileError:
            w = np.abs(prep.rows(prep.speed))
            thr = excitation.CLEAR * excitation.row_noise(prep)
            refused.append(
                f"  {null.counts} counts, {null.fs:g} Hz, {null.profile}: "
                f"median |ω| {np.median(w):.3g}, threshold {thr:.3g} rad/s"
            )
    lo, hi = clopper_pearson(len(refused), a.nulls)
    share = 100 * len(refused) / a.nulls
    print(f"refused {len(refused)}/{a.nulls} = {share:.2f} % ({100 * lo:.2f}-{100 * hi:.2f} %)")
    print("\n".join(refused))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
