"""Where an outsider null's low-frequency colour comes from (docs/measurements/quantlow.md).

    nice -n 19 .venv/bin/python scripts/quantlow_trace.py 7000     # o07000; 7022, 7026 likewise

The record is drawn again twice from its seed (tests/outsider_bench.py): with its own encoder and
with 2²² counts/rev (the same shaft, the quantisation ≈ 0). Both go through the doctor's design;
the baseline is fitted by its GLS on the rows the doctor keeps. Printed: the colour test on the
residual with the acceleration rows (y) and the regressors (X) each from the coarse or the fine
record; the spectrum of y_coarse − y_fine (the quantisation in the rows) against the floor, over
the rows kept (gaps zero, as quantfloor's doctor passed them) and over every row; the same with
the gaps' edges ramped (tvsd.analysis.quantisation.gated) for a few ramp lengths.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
import outsider_bench as ob

from tvsd.analysis import absorber
from tvsd.analysis import calibrate as C
from tvsd.analysis import design as D
from tvsd.analysis import quantisation as Q
from tvsd.analysis.dataset import ROTARY, Dataset
from tvsd.analysis.gls import gls
from tvsd.analysis.noise import _in_band, _welch, colour_test
from tvsd.analysis.prep import Band, prepare

BANDS = ((0.5, 1), (1, 2), (2, 4), (4, 8), (8, 16), (16, 32), (32, 50))


def record(seed: int, cpr: int | None) -> Dataset:
    s = ob.draw(seed, "none", 0.0)
    if cpr is not None:
        s.sensor["cpr"] = cpr
    cols = ob.make(s)
    meta = {"encoder_counts_per_rev": str(s.sensor["cpr"])}
    omega = np.round(cols["omega"], 7)
    return Dataset(
        s.name, cols["t"], cols["u"], cols["phi"], omega, s.fs, 1.0, 0.0, ROTARY, s.unit == "N", meta=meta
    )


def ratio(x: np.ndarray, rate: float, floor: Q.Floor) -> list[float]:
    f, p, _ = _welch(x, rate)
    return [
        round(float(np.mean(p[(f >= a) & (f < b)]) / np.mean(floor(f[(f >= a) & (f < b)]))), 2)
        for a, b in BANDS
    ]


def main(seed: int) -> None:
    coarse, fine = record(seed, None), record(seed, 2**22)
    pq, pf = prepare(coarse, Band()), prepare(fine, Band())
    dq = absorber.absorb(D.build(pq, coarse.offset_term, True))
    df = absorber.absorb(D.build(pf, fine.offset_term, True))
    out = C.test_all(dq, seed=0, boot=20)
    keep, rate = out.keep, coarse.sample_rate_hz / pq.band.decim
    floor = Q.floor(pq, keep)
    assert floor is not None
    print(
        f"{coarse.name}: {coarse.meta['encoder_counts_per_rev']} counts, {coarse.sample_rate_hz:g} Hz, "
        f"rows kept {keep.mean():.3f}, gap edges {np.count_nonzero(np.diff(keep.astype(int)))}"
    )

    def resid(y: np.ndarray, X: np.ndarray) -> np.ndarray:
        return np.where(keep, y - X @ gls(y, X, out.ar, keep).theta, 0.0)

    for tag, y, X in (
        ("coarse y, coarse X", dq.y, dq.X),
        ("coarse y, fine X", dq.y, df.X),
        ("fine y, coarse X", df.y, dq.X),
    ):
        r = resid(y, X)
        f, p, _ = _welch(r, rate)
        seen = _in_band(f, p, 100.0, floor)[0]
        top = float(seen[-1]) if len(seen) else 0.0  # none left: the floor passes the lowest bins
        print(f"  {tag:20s} colour p {colour_test(r, rate, 100.0, floor)[1]:.2g} (band to {top:.1f} Hz)")
    every = Q.floor(pq, np.ones(len(keep), dtype=bool))
    assert every is not None
    print("  (y_coarse − y_fine) / floor per band", [f"{a}–{b} Hz" for a, b in BANDS])
    print("    gaps zero (hard edges):", ratio(np.where(keep, dq.y - df.y, 0.0), rate, floor))
    print("    every row:             ", ratio(dq.y - df.y, rate, every))
    r = resid(dq.y, dq.X)
    for seconds in (0.02, 0.05, 0.1, 0.2):
        w = Q.edge_taper(keep, rate, seconds)
        fw = Q.floor(pq, w * w)
        assert fw is not None
        p = colour_test(w * r, rate, 100.0, fw)[1]
        print(
            f"    ramped {seconds:4.2f} s:          ", ratio(w * (dq.y - df.y), rate, fw), f"colour p {p:.2g}"
        )


if __name__ == "__main__":
    main(int(sys.argv[1]))
