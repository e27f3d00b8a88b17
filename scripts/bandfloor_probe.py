"""Where the quantisation floor leaves a recording's residual spectrum: the doctor on one file, then
its residual's Welch spectrum against the floor and the flat level, band by band, and the colour
test over the band it saw and over the whole band (the floor in both shapes).

    nice -n 19 .venv/bin/python scripts/bandfloor_probe.py FILE.csv
"""

from __future__ import annotations

import math
import sys

import numpy as np
from scipy.stats import chi2

from tvsd.analysis import noise, quantisation
from tvsd.analysis.dataset import load
from tvsd.analysis.doctor import diagnose
from tvsd.config import load_config


def main() -> int:
    cfg = load_config()
    data = load(sys.argv[1], cfg)
    dg = diagnose(data, cfg.plant.v0)
    prep, keep = dg.design.prep, dg.outcome.keep
    rate = 1.0 / float(np.median(np.diff(prep.t_rows)))
    w = quantisation.edge_taper(keep, rate)
    floor = quantisation.floor(prep, w * w)
    f, p = dg.noise.freq, dg.noise.psd
    nper = 2 * (len(f) - 1)
    segments = max(1, 2 * len(keep) // nper - 1)
    print(f"{data.name}: cause {dg.cause}; bands {dg.noise.colour_band_hz} / {dg.noise.peak_band_hz}")
    print(f"colour p over the band seen: {dg.noise.colour_p:.3g} (τ {1e3 * dg.noise.tau_s:.2g} ms)")
    n = dg.noise
    lrs = f"LR {n.peak_white_lr:.1f}/{n.peak_lr:.1f}"
    print(f"peak {n.peak_hz:.2f} Hz Q {n.peak_q:.3g} {lrs} over floor {n.peak_over_floor:.3g}")
    if floor is None:
        print("no floor: ω is not a count difference")
        return 0
    fm, pm, known, a0, _ = noise._whole_band(f, p, 100.0, floor)
    white, best = noise._colour_fits(fm, pm, known, a0, noise._slope(fm, pm, known))
    lr = max(0.0, 2 * noise.effective_segments(segments, nper) * (white.fun - best.fun))
    tau = math.exp(best.x[2])
    print(f"colour over the whole band, floor in both shapes: p {chi2.sf(lr, 1):.3g} (τ {1e3 * tau:.2g} ms)")
    for lo, hi in ((0.5, 2), (2, 5), (5, 10), (10, 20), (20, 30), (30, 40), (40, 50)):
        m = (fm >= lo) & (fm < hi)
        ratios = f"spectrum/flat {np.mean(pm[m]) / a0:8.3g}, floor/flat {np.mean(known[m]) / a0:8.3g}"
        print(f"  {lo:>4}–{hi:<3} Hz: {ratios}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
